#!/usr/bin/env bash
# Set up feed_twin from nothing on Debian 12: system tools, .venv with Python 3.11, the pinned
# dependencies, feed_twin itself (editable) and the msgs/ interface package built into .venv.
#
#   tools/setup.sh           full set-up; a no-op (< 1 s) when nothing changed since the last run
#   tools/setup.sh --check   only check (and, as root, install) the system tools
#   tools/setup.sh --status  say whether a set-up is needed, change nothing
#   tools/setup.sh --hash    print the hash of the set-up inputs that the stamp records
#
# Environment:
#   FEED_TWIN_NO_AUTO_INSTALL=1   never call apt-get, even as root; name the missing package
#   FEED_TWIN_PYTHON=...          interpreter to create .venv with (default: python3.11 on PATH)
#   FEED_TWIN_VENV=...            virtual environment directory (default: <repo>/.venv)
#
# The tool checks use bash builtins only, so they give their one-line answer even with a PATH
# that lacks everything.

set -o errexit -o nounset -o pipefail

here="${BASH_SOURCE[0]%/*}"
[[ "$here" == "${BASH_SOURCE[0]}" ]] && here="."
repo="$(cd "$here/.." && pwd)"
venv="${FEED_TWIN_VENV:-$repo/.venv}"
python_cmd="${FEED_TWIN_PYTHON:-python3.11}"
stamp="$venv/feed_twin-setup.stamp"

say() { printf 'setup: %s\n' "$*"; }
die() {
    printf 'setup: error: %s\n' "$*" >&2
    exit 1
}

is_root() { [[ "${EUID:-$(id -u)}" -eq 0 ]]; }
may_auto_install() { is_root && [[ -z "${FEED_TWIN_NO_AUTO_INSTALL:-}" ]]; }

apt_updated=0
apt_install() {
    export DEBIAN_FRONTEND=noninteractive
    local log="${TMPDIR:-/tmp}/feed_twin-apt-$$.log"
    if [[ $apt_updated -eq 0 ]]; then
        apt-get update -qq >"$log" 2>&1 || die "apt-get update failed: $(tail -n 1 "$log")"
        apt_updated=1
    fi
    apt-get install -y -qq --no-install-recommends "$@" >"$log" 2>&1 ||
        die "apt-get install $* failed: $(tail -n 1 "$log") (log: $log)"
    rm -f "$log"
}

# The Debian packages behind each missing tool, in one list (no duplicates, stable order).
missing_packages() {
    local -a pkgs=()
    if ! command -v "$python_cmd" >/dev/null 2>&1; then
        pkgs+=(python3.11 python3.11-venv python3.11-dev)
    else
        # venv needs ensurepip (python3.11-venv); the message extension needs Python.h (-dev).
        "$python_cmd" -c 'import ensurepip, venv' >/dev/null 2>&1 || pkgs+=(python3.11-venv)
        "$python_cmd" -c 'import os, sysconfig, sys
sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()["include"], "Python.h")))' \
            >/dev/null 2>&1 || pkgs+=(python3.11-dev)
    fi
    command -v cmake >/dev/null 2>&1 || pkgs+=(cmake)
    command -v g++ >/dev/null 2>&1 || pkgs+=(g++)
    command -v make >/dev/null 2>&1 || pkgs+=(make)
    # LinuxCNC 2.9 (feed_twin/linuxcnc): the controller, and halcompile for feedtwin_clock
    command -v linuxcnc >/dev/null 2>&1 || pkgs+=(linuxcnc-uspace)
    command -v halcompile >/dev/null 2>&1 || pkgs+=(linuxcnc-uspace-dev)
    printf '%s\n' "${pkgs[@]}"
}

check_tools() {
    local -a missing
    local version
    # The ROS 2 Jazzy wheels are built for CPython 3.11 only.
    if command -v "$python_cmd" >/dev/null 2>&1; then
        version="$("$python_cmd" -c 'import sys; print("%d.%d" % sys.version_info[:2])' 2>&1)" ||
            version="unusable"
        [[ "$version" == "3.11" ]] ||
            die "$python_cmd is Python $version; feed_twin needs 3.11 (the ROS 2 Jazzy wheels are cp311)"
    fi
    mapfile -t missing < <(missing_packages)
    [[ ${#missing[@]} -eq 0 || -z "${missing[0]}" ]] && return 0
    if may_auto_install; then
        say "installing Debian packages: ${missing[*]}"
        apt_install "${missing[@]}"
        mapfile -t missing < <(missing_packages)
        [[ ${#missing[@]} -eq 0 || -z "${missing[0]}" ]] && return 0
        die "still missing after apt-get install: ${missing[*]}"
    fi
    die "missing Debian package(s) ${missing[*]}: run 'sudo apt-get install ${missing[*]}'"
}

# Nice to have for the tests: Rerun's headless screenshots render with Vulkan on lavapipe, and
# the live viewer's test loads its web page in a headless Chromium (driven by Playwright).
optional_packages() {
    local -a want=(mesa-vulkan-drivers chromium) absent=()
    local pkg
    for pkg in "${want[@]}"; do
        dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" ||
            absent+=("$pkg")
    done
    [[ ${#absent[@]} -eq 0 ]] && return 0
    if may_auto_install; then
        say "installing Debian packages for the tests: ${absent[*]}"
        apt_install "${absent[@]}"
    else
        say "note: not installing ${absent[*]} (not root); the headless screenshot and browser tests need them"
    fi
}

# LinuxCNC's rtapi_app refuses to run as root: feed_twin runs LinuxCNC as this system user when
# it is started as root (feed_twin/linuxcnc/runner.py; FEED_TWIN_LINUXCNC_USER names another).
lcnc_user="${FEED_TWIN_LINUXCNC_USER:-feedtwin}"
lcnc_comp="$repo/config/linuxcnc/feedtwin_clock.comp"
lcnc_module="/usr/lib/linuxcnc/modules/feedtwin_clock.so"
lcnc_stamp="$venv/feed_twin-linuxcnc.stamp"

lcnc_hash() { sha256sum "$lcnc_comp" | cut -d' ' -f1; }

linuxcnc_ready() {
    [[ -f "$lcnc_module" && -f "$lcnc_stamp" && "$(cat "$lcnc_stamp")" == "$(lcnc_hash)" ]] &&
        { ! is_root || id -u "$lcnc_user" >/dev/null 2>&1; }
}

# The servo thread's clock component (a HAL realtime module) goes where `loadrt` finds it, which
# needs root; so does the unprivileged user.
setup_linuxcnc() {
    linuxcnc_ready && return 0
    if ! is_root; then
        [[ -f "$lcnc_module" ]] ||
            die "LinuxCNC lacks the HAL component feedtwin_clock: run 'sudo tools/setup.sh' once"
        lcnc_hash >"$lcnc_stamp"
        return 0
    fi
    if ! id -u "$lcnc_user" >/dev/null 2>&1; then
        say "creating the system user $lcnc_user that runs LinuxCNC (rtapi_app refuses root)"
        useradd --system --create-home --home-dir "/var/lib/$lcnc_user" \
            --shell /usr/sbin/nologin "$lcnc_user" || die "useradd $lcnc_user failed"
    fi
    local tmp
    tmp="$(mktemp -d)"
    cp "$lcnc_comp" "$tmp/"
    (cd "$tmp" && halcompile --install feedtwin_clock.comp) >"$tmp/halcompile.log" 2>&1 ||
        die "halcompile --install $lcnc_comp failed: $(tail -n 1 "$tmp/halcompile.log")"
    rm -rf "$tmp"
    lcnc_hash >"$lcnc_stamp"
    say "installed LinuxCNC's HAL component feedtwin_clock"
}

# Everything the set-up result depends on; a change in any of these reruns the set-up.
inputs_hash() {
    (
        cd "$repo"
        printf '%s\n' "$python_cmd" "$venv"
        cat requirements.txt constraints.txt pyproject.toml tools/setup.sh tools/build_msgs.sh
        find msgs -path msgs/build -prune -o -type f -print | LC_ALL=C sort | xargs cat
    ) | sha256sum | cut -d' ' -f1
}

venv_up_to_date() {
    [[ -f "$stamp" && -x "$venv/bin/python" && -x "$venv/bin/feed-twin" ]] &&
        [[ -f "$venv/share/feed_twin_msgs/package.xml" ]] &&
        [[ "$(cat "$stamp")" == "$(inputs_hash)" ]]
}

up_to_date() { venv_up_to_date && linuxcnc_ready; }

run_logged() {
    local log="$1"
    shift
    if ! "$@" >"$log" 2>&1; then
        tail -n 25 "$log" >&2
        die "'$*' failed; full log: $log"
    fi
}

main() {
    if [[ "${1:-}" == "--check" ]]; then
        check_tools
        say "system tools present"
        return 0
    fi
    if [[ "${1:-}" == "--status" ]]; then
        if up_to_date; then say "up to date ($venv)"; else say "set-up needed ($venv)"; fi
        return 0
    fi
    if [[ "${1:-}" == "--hash" ]]; then
        inputs_hash
        return 0
    fi
    [[ $# -eq 0 ]] || die "unknown argument '$1' (use --check, --status, --hash or nothing)"

    local t0=$SECONDS
    if up_to_date; then
        say "up to date ($venv)"
        return 0
    fi
    check_tools
    if venv_up_to_date; then
        setup_linuxcnc
        say "up to date ($venv)"
        return 0
    fi

    # Several shells may run `make test` in one tree at once: one set-up at a time, and the
    # ones that waited find it done.
    local logdir="$repo/msgs/build"
    mkdir -p "$logdir"
    exec 9>"$logdir/setup.lock"
    if ! flock -n 9; then
        say "waiting for another set-up in this tree to finish"
        flock 9
    fi
    if up_to_date; then
        say "up to date ($venv)"
        return 0
    fi
    # apt-get (disk, one core) overlaps with pip (network first) instead of adding to it.
    optional_packages &
    local optional_pid=$!

    if [[ -e "$venv" ]] && ! "$venv/bin/python" -c 'import sys; assert sys.version_info[:2] == (3, 11)' \
        >/dev/null 2>&1; then
        say "removing unusable $venv"
        rm -rf "$venv"
    fi
    if [[ ! -e "$venv" ]]; then
        say "creating $venv with $("$python_cmd" -c 'import sys; print(sys.executable)')"
        "$python_cmd" -m venv "$venv"
    fi
    rm -f "$stamp"

    local t_pip=$SECONDS
    say "installing pinned dependencies (requirements.txt, constraints.txt)"
    run_logged "$logdir/pip.log" "$venv/bin/python" -m pip install -q --upgrade pip \
        -c "$repo/constraints.txt"
    # --no-compile: compileall on all cores does it below, after msgs/ is in the environment.
    run_logged "$logdir/pip.log" "$venv/bin/python" -m pip install -q --no-compile \
        -r "$repo/requirements.txt" -c "$repo/constraints.txt"
    say "installing feed_twin (editable)"
    run_logged "$logdir/pip-editable.log" "$venv/bin/python" -m pip install -q --no-deps \
        -e "$repo"

    local t_msgs=$SECONDS
    say "building msgs/ (feed_twin_msgs) into $venv"
    bash "$repo/tools/build_msgs.sh" "$venv"
    t_msgs=$((SECONDS - t_msgs))

    # Byte-compile the environment and feed_twin once. Where PYTHONDONTWRITEBYTECODE is set (it is on the CI
    # machines) Python never writes a .pyc, so without this every process compiled numpy, numba,
    # scipy and rclpy from source again: a cold engine run took 1.8 s instead of 0.8 s, and each
    # node process of the test suite paid the same second.
    local t_pyc=$SECONDS
    # (not run_logged: a stray file that does not compile must not stop the set-up)
    "$venv/bin/python" -m compileall -q -j 0 \
        "$("$venv/bin/python" -c 'import sysconfig; print(sysconfig.get_path("purelib"))')" \
        "$repo/feed_twin" >"$logdir/compileall.log" 2>&1 \
        || say "note: byte-compiling reported errors (see $logdir/compileall.log)"
    say "byte-compiled the environment in $((SECONDS - t_pyc)) s"

    # Rerun asks once per machine whether it may send usage analytics; answer no.
    "$venv/bin/rerun" analytics disable >/dev/null 2>&1 || say "note: 'rerun analytics disable' failed"

    wait "$optional_pid" || say "note: the optional Debian packages were not installed (see above)"
    setup_linuxcnc

    inputs_hash >"$stamp"
    say "done in $((SECONDS - t0)) s (pip $((SECONDS - t_pip - t_msgs)) s, msgs/ $t_msgs s)"
}

main "$@"
