"""The set-up's error paths: missing system tools give one line naming the Debian packages (or
are installed when root), a broken message definition gives its file and line, a failed CMake
step gives the relevant lines and the log path; the stamp makes a repeated set-up a no-op."""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SETUP = REPO / "tools" / "setup.sh"
BUILD_MSGS = REPO / "tools" / "build_msgs.sh"
CHECK_MSGS = REPO / "tools" / "check_msgs.py"
VENV = Path(sys.prefix)
BASH = shutil.which("bash") or "/bin/bash"


def _real(command: str) -> str:
    path = shutil.which(command)
    if path is None:
        pytest.skip(f"{command} is not installed on this machine")
    return os.path.realpath(path)


def _tool_dir(tmp_path: Path, commands: dict[str, str]) -> Path:
    """A directory to use as the whole PATH, holding only the given commands."""
    directory = tmp_path / "bin"
    directory.mkdir()
    for name, target in commands.items():
        (directory / name).symlink_to(target)
    return directory


def _python311() -> str:
    # The real interpreter binary (not a pyenv shim, which needs its own PATH).
    return os.path.realpath(getattr(sys, "_base_executable", sys.executable))


def _run(args: list[str], path: Path | str, **env: str) -> subprocess.CompletedProcess[str]:
    environment = {"PATH": str(path), "HOME": os.environ.get("HOME", "/tmp"), **env}
    return subprocess.run(
        [BASH, *args], capture_output=True, text=True, env=environment, timeout=120
    )


def test_missing_everything_names_all_debian_packages_in_one_line(tmp_path):
    result = _run([str(SETUP), "--check"], tmp_path / "empty", FEED_TWIN_NO_AUTO_INSTALL="1")
    assert result.returncode == 1
    assert result.stdout == ""
    assert result.stderr.splitlines() == [
        "setup: error: missing Debian package(s) python3.11 python3.11-venv python3.11-dev "
        "cmake g++ make linuxcnc-uspace linuxcnc-uspace-dev: run 'sudo apt-get install "
        "python3.11 python3.11-venv python3.11-dev cmake g++ make linuxcnc-uspace "
        "linuxcnc-uspace-dev'"
    ]


def _linuxcnc() -> dict[str, str]:
    return {"linuxcnc": _real("linuxcnc"), "halcompile": _real("halcompile")}


def test_missing_cmake_and_gxx_are_named(tmp_path):
    tools = _tool_dir(tmp_path, {"python3.11": _python311(), "make": _real("make"), **_linuxcnc()})
    result = _run([str(SETUP), "--check"], tools, FEED_TWIN_NO_AUTO_INSTALL="1")
    assert result.returncode == 1
    assert result.stderr.splitlines() == [
        "setup: error: missing Debian package(s) cmake g++: run 'sudo apt-get install cmake g++'"
    ]
    assert "Traceback" not in result.stderr


def test_all_tools_present_passes_the_check(tmp_path):
    tools = _tool_dir(
        tmp_path,
        {
            "python3.11": _python311(),
            "cmake": _real("cmake"),
            "g++": _real("g++"),
            "make": _real("make"),
            **_linuxcnc(),
        },
    )
    result = _run([str(SETUP), "--check"], tools, FEED_TWIN_NO_AUTO_INSTALL="1")
    assert (result.returncode, result.stdout, result.stderr) == (
        0,
        "setup: system tools present\n",
        "",
    )


def _fake_apt_get(tools: Path, log: Path, provides: dict[str, str]) -> None:
    """An apt-get that records its arguments and 'installs' by linking the given commands."""
    links = "".join(f"/bin/ln -sf {target} {tools / name}\n" for name, target in provides.items())
    script = tools / "apt-get"
    script.write_text(
        f'#!{BASH}\necho "$*" >> {log}\nif [ "$1" = install ]; then\n{links}fi\nexit 0\n'
    )
    script.chmod(0o755)
    for command in ("tail", "rm"):  # the set-up's apt-get wrapper keeps a log
        (tools / command).symlink_to(_real(command))


@pytest.mark.skipif(os.geteuid() != 0, reason="auto-install only runs as root")
def test_as_root_missing_tools_are_installed_with_apt_get(tmp_path):
    tools = _tool_dir(tmp_path, {"python3.11": _python311(), "make": _real("make"), **_linuxcnc()})
    log = tmp_path / "apt.log"
    _fake_apt_get(tools, log, {"cmake": _real("cmake"), "g++": _real("g++")})
    result = _run([str(SETUP), "--check"], tools)
    assert result.returncode == 0, result.stderr
    assert result.stdout.splitlines() == [
        "setup: installing Debian packages: cmake g++",
        "setup: system tools present",
    ]
    assert log.read_text().splitlines() == [
        "update -qq",
        "install -y -qq --no-install-recommends cmake g++",
    ]


@pytest.mark.skipif(os.geteuid() != 0, reason="auto-install only runs as root")
def test_as_root_a_package_that_does_not_provide_the_tool_is_reported(tmp_path):
    tools = _tool_dir(tmp_path, {"python3.11": _python311(), "make": _real("make"), **_linuxcnc()})
    _fake_apt_get(tools, tmp_path / "apt.log", {"cmake": _real("cmake")})
    result = _run([str(SETUP), "--check"], tools)
    assert result.returncode == 1
    assert result.stderr.splitlines() == ["setup: error: still missing after apt-get install: g++"]


def test_unknown_argument_is_named():
    result = _run([str(SETUP), "--frobnicate"], os.environ["PATH"])
    assert result.returncode == 1
    assert result.stderr.splitlines() == [
        "setup: error: unknown argument '--frobnicate' (use --check, --status, --hash or nothing)"
    ]


def test_the_stamp_decides_whether_a_set_up_is_needed(tmp_path):
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    (venv / "share" / "feed_twin_msgs").mkdir(parents=True)
    for name in ("python", "feed-twin"):
        (venv / "bin" / name).symlink_to(_python311())
    (venv / "share" / "feed_twin_msgs" / "package.xml").write_text("<package/>")
    env = {"FEED_TWIN_VENV": str(venv), "FEED_TWIN_NO_AUTO_INSTALL": "1"}
    path = os.environ["PATH"]

    assert _run([str(SETUP), "--status"], path, **env).stdout == f"setup: set-up needed ({venv})\n"
    digest = _run([str(SETUP), "--hash"], path, **env).stdout.strip()
    assert len(digest) == 64
    (venv / "feed_twin-setup.stamp").write_text(digest + "\n")
    # LinuxCNC's clock component counts too: installed, and the stamp names its source
    assert _run([str(SETUP), "--status"], path, **env).stdout == f"setup: set-up needed ({venv})\n"
    comp = REPO / "config" / "linuxcnc" / "feedtwin_clock.comp"
    (venv / "feed_twin-linuxcnc.stamp").write_text(hashlib.sha256(comp.read_bytes()).hexdigest())
    assert _run([str(SETUP), "--status"], path, **env).stdout == f"setup: up to date ({venv})\n"
    # The full set-up with an unchanged stamp is a no-op that touches nothing. Its PATH holds
    # only what the stamp check uses: were the stamp stale, it would stop at the tool check
    # instead of installing into the fake venv.
    hashing = {
        name: _real(name) for name in ("cat", "find", "sort", "xargs", "sha256sum", "cut", "id")
    }
    result = _run([str(SETUP)], _tool_dir(tmp_path, hashing), **env)
    assert (result.returncode, result.stdout) == (0, f"setup: up to date ({venv})\n")
    # Another interpreter changes the inputs, so the stamp no longer matches.
    other = {**env, "FEED_TWIN_PYTHON": "python3.11-other"}
    assert _run([str(SETUP), "--status"], path, **other).stdout == (
        f"setup: set-up needed ({venv})\n"
    )


def _msgs_copy(tmp_path: Path) -> Path:
    copy = tmp_path / "msgs"
    shutil.copytree(REPO / "msgs", copy, ignore=shutil.ignore_patterns("build"))
    return copy


def _replace(path: Path, old: str, new: str) -> None:
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))


def test_a_broken_msg_file_gives_its_file_line_and_reason(tmp_path):
    msgs = _msgs_copy(tmp_path)
    broken = msgs / "msg" / "AxisCommand.msg"
    _replace(broken, "float64 velocity  #", "flaot64 velocity  #")
    number = 1 + [x.startswith("flaot64") for x in broken.read_text().splitlines()].index(True)
    result = _run([str(BUILD_MSGS), str(VENV), str(msgs)], os.environ["PATH"])
    assert result.returncode == 1
    lines = result.stderr.splitlines()
    assert lines[0] == f"build_msgs: the message definitions in {msgs} do not parse:"
    assert len(lines) == 2
    assert lines[1].startswith(f"    {broken}:{number}: flaot64 velocity  # table velocity")
    assert lines[1].endswith(
        "'flaot64' is an invalid message name. It should have the pattern '^[A-Z][A-Za-z0-9]*$'"
    )
    assert not (msgs / "build" / "CMakeCache.txt").exists()  # stopped before CMake


def _check_msgs(msgs: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, str(CHECK_MSGS), str(msgs), str(VENV)],
        capture_output=True,
        text=True,
        timeout=60,
    )


def test_check_msgs_accepts_the_project_package():
    result = _check_msgs(REPO / "msgs")
    assert (result.returncode, result.stderr) == (0, "")


def test_check_msgs_names_an_unknown_type_and_an_unlisted_file(tmp_path):
    msgs = _msgs_copy(tmp_path)
    _replace(msgs / "msg" / "AxisState.msg", "std_msgs/Header header", "std_msgs/Headr header")
    (msgs / "msg" / "Extra.msg").write_text("float64 x  # [m]\n")
    result = _check_msgs(msgs)
    assert result.returncode == 1
    assert result.stderr.splitlines() == [
        f"{msgs}/msg/Extra.msg:1: not listed in rosidl_generate_interfaces of {msgs}",
        f"{msgs}/msg/AxisState.msg:5: std_msgs/Headr header  # stamp = simulation time of the "
        f"state: unknown message type 'std_msgs/Headr' (not in feed_twin_msgs nor in {VENV})",
    ]


def test_check_msgs_names_a_duplicate_field(tmp_path):
    msgs = _msgs_copy(tmp_path)
    path = msgs / "msg" / "TwinResidual.msg"
    path.write_text(path.read_text() + "float64 rms_window  # again [s]\n")
    result = _check_msgs(msgs)
    assert result.returncode == 1
    number = len(path.read_text().splitlines())
    assert result.stderr.startswith(f"{path}:{number}: float64 rms_window  # again [s]: ")
    assert "rms_window" in result.stderr.split(": ", 2)[2]


def test_check_msgs_names_a_listed_but_absent_file(tmp_path):
    msgs = _msgs_copy(tmp_path)
    (msgs / "msg" / "HealthStatus.msg").unlink()
    result = _check_msgs(msgs)
    assert result.stderr.splitlines() == [
        f"{msgs}/CMakeLists.txt:1: lists msg/HealthStatus.msg, which is absent"
    ]


@pytest.mark.slow
def test_a_failed_cmake_step_shows_the_relevant_lines_and_the_log(tmp_path):
    msgs = _msgs_copy(tmp_path)
    _replace(
        msgs / "CMakeLists.txt",
        "find_package(std_msgs REQUIRED)",
        "find_package(std_msgs REQUIRED)\nfind_package(no_such_msgs REQUIRED)",
    )
    result = _run([str(BUILD_MSGS), str(VENV), str(msgs)], os.environ["PATH"])
    assert result.returncode == 1
    lines = result.stderr.splitlines()
    log = msgs / "build" / "build.log"
    assert lines[0] == "build_msgs: cmake configure failed; the relevant lines:"
    assert lines[-1] == f"build_msgs: full log: {log}"
    assert any("CMake Error at CMakeLists.txt" in line for line in lines)
    assert any("no_such_msgs" in line for line in lines)
    # A short excerpt, not the whole log.
    assert len(lines) <= 32
    assert len(lines) < len(log.read_text().splitlines())
    assert "Detecting CXX compiler ABI info" not in result.stderr


@pytest.mark.skipif(os.geteuid() != 0, reason="auto-install only runs as root")
def test_as_root_a_failing_apt_get_is_reported_with_its_last_line(tmp_path):
    tools = _tool_dir(tmp_path, {"python3.11": _python311(), "make": _real("make"), **_linuxcnc()})
    _fake_apt_get(tools, tmp_path / "apt.log", {})
    (tools / "apt-get").write_text(
        f"#!{BASH}\n"
        'if [ "$1" = install ]; then echo "E: Unable to locate package g++"; exit 100; fi\n'
    )
    result = _run([str(SETUP), "--check"], tools, TMPDIR=str(tmp_path))
    assert result.returncode == 1
    log = (
        tmp_path / f"feed_twin-apt-{result.stderr.split('feed_twin-apt-')[1].split('.log')[0]}.log"
    )
    assert result.stderr.splitlines() == [
        "setup: error: apt-get install cmake g++ failed: E: Unable to locate package g++ "
        f"(log: {log})"
    ]
    assert log.read_text() == "E: Unable to locate package g++\n"


def test_a_python_other_than_3_11_is_refused_with_the_reason(tmp_path):
    tools = _tool_dir(tmp_path, {})
    fake = tools / "python3.11"
    fake.write_text(f"#!{BASH}\necho 3.12\n")
    fake.chmod(0o755)
    result = _run([str(SETUP), "--check"], tools, FEED_TWIN_NO_AUTO_INSTALL="1")
    assert result.returncode == 1
    assert result.stderr.splitlines() == [
        "setup: error: python3.11 is Python 3.12; feed_twin needs 3.11 "
        "(the ROS 2 Jazzy wheels are cp311)"
    ]


RUN_TESTS = REPO / "tools" / "run_tests.sh"


def _fake_venv_tools(tmp_path: Path, *, ruff: int, pyright: int, pytest_status: int) -> Path:
    """A venv whose ruff, pyright and pytest only record their arguments and exit with the given
    codes."""
    venv = tmp_path / "venv"
    (venv / "bin").mkdir(parents=True)
    for name, status in (("ruff", ruff), ("pyright", pyright), ("pytest", pytest_status)):
        script = venv / "bin" / name
        script.write_text(f'#!{BASH}\necho "{name} $*"\nexit {status}\n')
        script.chmod(0o755)
    return venv


@pytest.mark.parametrize(
    ("ruff", "pyright", "pytest_status", "status", "last_line"),
    [
        (0, 0, 0, 0, "pytest -m not slow"),
        (0, 0, 5, 0, "run_tests: pytest collected no tests"),
        (0, 0, 1, 1, "run_tests: FAILED: pytest (exit 1)"),
        (1, 0, 0, 1, "run_tests: FAILED: ruff check, ruff format"),
        (0, 1, 0, 1, "run_tests: FAILED: pyright"),
        (1, 1, 2, 1, "run_tests: FAILED: ruff check, ruff format, pyright, pytest (exit 2)"),
    ],
)
def test_the_test_runner_runs_everything_and_combines_the_outcomes(
    tmp_path, ruff, pyright, pytest_status, status, last_line
):
    venv = _fake_venv_tools(tmp_path, ruff=ruff, pyright=pyright, pytest_status=pytest_status)
    result = subprocess.run(
        [BASH, str(RUN_TESTS), "-m", "not slow"],
        capture_output=True,
        text=True,
        env={**os.environ, "FEED_TWIN_VENV": str(venv)},
        timeout=60,
    )
    assert result.returncode == status
    lines = result.stdout.splitlines()
    # pytest runs even when ruff or pyright failed, so its summary is always printed.
    assert "ruff check ." in lines and "ruff format --check ." in lines
    assert f"pyright --project pyproject.toml --pythonpath {venv}/bin/python" in lines
    assert "pytest -m not slow" in lines
    assert lines[-1] == last_line


def test_the_msgs_tools_state_their_usage():
    check = subprocess.run(
        [sys.executable, str(CHECK_MSGS)], capture_output=True, text=True, timeout=60
    )
    assert (check.returncode, check.stderr) == (2, "usage: check_msgs.py MSGS_DIR PREFIX\n")
    build = _run([str(BUILD_MSGS)], os.environ["PATH"])
    assert (build.returncode, build.stderr) == (
        2,
        "usage: tools/build_msgs.sh VENV [SOURCE_DIR [BUILD_DIR]]\n",
    )


@pytest.mark.slow
def test_a_build_tree_of_another_checkout_is_started_afresh(tmp_path):
    msgs = _msgs_copy(tmp_path)
    _replace(
        msgs / "CMakeLists.txt",
        "find_package(std_msgs REQUIRED)",
        "find_package(std_msgs REQUIRED)\nfind_package(no_such_msgs REQUIRED)",
    )
    build = msgs / "build"
    build.mkdir()
    (build / "CMakeCache.txt").write_text(
        "CMAKE_HOME_DIRECTORY:INTERNAL=/elsewhere/msgs\nCMAKE_INSTALL_PREFIX:PATH=/elsewhere/.venv\n"
    )
    (build / "stale_object.o").write_text("")
    result = _run([str(BUILD_MSGS), str(VENV), str(msgs)], os.environ["PATH"])
    assert not (build / "stale_object.o").exists()
    # CMake ran on a clean tree: it reports the real error, not a cache from another checkout.
    assert "does not match the source" not in result.stderr  # CMake's words for that
    assert any("no_such_msgs" in line for line in result.stderr.splitlines())
    cache = (build / "CMakeCache.txt").read_text()
    assert f"CMAKE_HOME_DIRECTORY:INTERNAL={msgs}" in cache
