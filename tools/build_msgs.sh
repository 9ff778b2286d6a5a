#!/usr/bin/env bash
# Build msgs/ (the ROS 2 interface package feed_twin_msgs) with cmake + g++ against the ROS 2
# Jazzy wheels in a virtual environment, and install it into that environment's prefix, so that
# nothing (no sourcing, no PYTHONPATH, no LD_LIBRARY_PATH) is needed at run time.
#
#   tools/build_msgs.sh VENV [SOURCE_DIR [BUILD_DIR]]
#
# SOURCE_DIR defaults to <repo>/msgs and BUILD_DIR to SOURCE_DIR/build. On failure it prints only
# the relevant CMake, rosidl and compiler lines, then the path of the full log, and exits 1.

set -o errexit -o nounset -o pipefail

here="${BASH_SOURCE[0]%/*}"
[[ "$here" == "${BASH_SOURCE[0]}" ]] && here="."
repo="$(cd "$here/.." && pwd)"

[[ $# -ge 1 && $# -le 3 ]] || {
    echo "usage: tools/build_msgs.sh VENV [SOURCE_DIR [BUILD_DIR]]" >&2
    exit 2
}
venv="$(cd "$1" && pwd)"
src="$(cd "${2:-$repo/msgs}" && pwd)"
build="${3:-$src/build}"
mkdir -p "$build"
build="$(cd "$build" && pwd)"
log="$build/build.log"

# The lines worth a person's attention in a CMake/rosidl/compiler log, at most 30 of them.
relevant_lines() {
    grep -E -A4 \
        'CMake Error|error:|Error:|Error parsing|Traceback|Exception|Invalid|invalid|does not|\*\*\*' \
        "$1" | grep -v -E '^--$|^-- |^\[ *[0-9]+%\]' | head -n 30
}

fail() {
    printf 'build_msgs: %s failed; the relevant lines:\n' "$1" >&2
    relevant_lines "$log" | sed 's/^/    /' >&2
    printf 'build_msgs: full log: %s\n' "$log" >&2
    exit 1
}

# rosidl finds its generators and typesupports through the ament index and CMake packages of
# the venv prefix only; a sourced ROS installation would mix two ROS builds.
export AMENT_PREFIX_PATH="$venv"
export CMAKE_PREFIX_PATH="$venv"
# the system's cmake (Debian's, which setup.sh installs): FMPy's dependencies put a cmake wheel
# of another major version into the venv's bin, first on the PATH below
cmake="$(PATH="${PATH//"$venv/bin:"/}" type -P cmake)" || {
    printf 'build_msgs: no cmake on the PATH; install the Debian package cmake\n' >&2
    exit 1
}
export PATH="$venv/bin:$PATH"

if ! "$venv/bin/python" "$repo/tools/check_msgs.py" "$src" "$venv" 2>"$log"; then
    printf 'build_msgs: the message definitions in %s do not parse:\n' "$src" >&2
    sed 's/^/    /' "$log" >&2
    exit 1
fi

# A build tree configured for another source tree or prefix (a moved checkout, another venv)
# makes CMake refuse or mix two installs: start that one afresh.
cache="$build/CMakeCache.txt"
if [[ -f "$cache" ]] &&
    ! { grep -qx "CMAKE_HOME_DIRECTORY:INTERNAL=$src" "$cache" &&
        grep -qx "CMAKE_INSTALL_PREFIX:PATH=$venv" "$cache"; }; then
    find "$build" -mindepth 1 -maxdepth 1 ! -name build.log ! -name 'pip*.log' \
        ! -name setup.lock -exec rm -rf {} +
fi

jobs="$(nproc 2>/dev/null || echo 2)"
"$cmake" -S "$src" -B "$build" \
    -DCMAKE_INSTALL_PREFIX="$venv" \
    -DCMAKE_BUILD_TYPE=Release \
    -DBUILD_TESTING=OFF \
    -DPython3_EXECUTABLE="$venv/bin/python" \
    >>"$log" 2>&1 || fail "cmake configure"
"$cmake" --build "$build" -j "$jobs" >>"$log" 2>&1 || fail "cmake build"

# Remove what a previous build installed, so a renamed or deleted message leaves nothing behind.
manifest="$build/install_manifest.txt"
if [[ -f "$manifest" ]]; then
    while IFS= read -r installed; do
        case "$installed" in
        "$venv"/*) rm -f "$installed" ;;
        esac
    done <"$manifest"
fi
"$cmake" --install "$build" >>"$log" 2>&1 || fail "cmake install"
