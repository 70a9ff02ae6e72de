"""Fixtures: a sim-host process on a free loopback port, killed after the test.

The simulator binary is $SIM_HOST_BIN, else target/debug/sim-host of this repository
($CARGO_TARGET_DIR respected), built with `cargo build -p sim-host` when missing.

The tests run from any directory (issue 31). From the repository root, a Python without
the package installed imports the Rust crate's folder `armctl/` as a namespace package
("module 'armctl' has no attribute 'connect'" in every test): `installed_armctl` stops the
run at once with what to do instead. Child Pythons start in a directory of their own, so
that `python -c` (which puts its working directory first on sys.path) never sees it.
"""

import os
import pathlib
import signal
import socket
import subprocess
import sys
import tempfile
import time

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]

# The tests send SIGINT, SIGTERM and SIGHUP to this process and to child Pythons and expect
# Python's defaults (KeyboardInterrupt, death), which the binding builds on. A test run
# started in the background by a script (`cmd &`: SIGINT and SIGQUIT ignored) or under
# nohup (SIGHUP ignored) inherits them ignored, and an ignored signal is rightly left alone
# by Python and by the binding: a fresh-clone `.ci/run` started so failed six tests ("DID
# NOT RAISE KeyboardInterrupt", "the script still runs 10 s after SIGHUP"). So the defaults
# are put back here, for this process and (handlers do not survive exec, SIG_DFL does)
# every child it starts.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
for _signum in (signal.SIGHUP, signal.SIGTERM):
    if signal.getsignal(_signum) == signal.SIG_IGN:
        signal.signal(_signum, signal.SIG_DFL)


def installed_armctl():
    """The armctl extension module, or a clear error if `import armctl` finds nothing or
    something else (the crate folder as a namespace package, from the repository root)."""
    what_to_do = (
        f"it is not installed in this Python ({sys.executable}). Install it "
        f"(python3 -m pip install ./armctl-py), or run the tests with the Python that has "
        f"it (.ci/run: target/armctl-py-venv/bin/python -m pytest armctl-py/tests); the "
        f"tests run from any directory.")
    try:
        import armctl
    except ImportError as e:
        raise ImportError(f"{e}: {what_to_do}") from e
    if not hasattr(armctl, "connect"):
        where = list(getattr(armctl, "__path__", [])) or getattr(armctl, "__file__", "?")
        raise ImportError(f"`import armctl` found {where}, not the armctl Python package: "
                          f"{what_to_do}")
    return armctl


try:
    installed_armctl()
except ImportError as e:
    pytest.exit(str(e), returncode=4)

# The working directory of child Pythons: not the caller's (see the module's doc).
CHILD_CWD = tempfile.gettempdir()


def sim_host_bin() -> pathlib.Path:
    if os.environ.get("SIM_HOST_BIN"):
        return pathlib.Path(os.environ["SIM_HOST_BIN"])
    target = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    binary = target / "debug" / "sim-host"
    if not binary.exists():
        subprocess.run(["cargo", "build", "-q", "-p", "sim-host"], cwd=ROOT, check=True)
    return binary


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class SimHost:
    def __init__(self, *args: str):
        self.dir = tempfile.TemporaryDirectory(prefix="armctl-py-")
        self.address = f"127.0.0.1:{free_port()}"
        self.process = subprocess.Popen(
            [str(sim_host_bin()), "--bind", self.address,
             "--settings", os.path.join(self.dir.name, "settings.txt"),
             "--log-level", "warn", *args],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        line = self.process.stdout.readline()
        if "listening" not in line:
            self.process.kill()
            raise RuntimeError(f"sim-host did not start: {line!r} {self.process.stderr.read()}")

    def close(self):
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.dir.cleanup()


@pytest.fixture
def sim():
    """A simulated controller (6 joints, real time)."""
    host = SimHost()
    yield host
    host.close()


@pytest.fixture
def python_child():
    """Starts `python3 -c SCRIPT ARGS...` with pipes; killed after the test."""
    children = []

    def start(script: str, *args: str) -> subprocess.Popen:
        child = subprocess.Popen([sys.executable, "-c", script, *args], cwd=CHILD_CWD,
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        children.append(child)
        return child

    yield start
    for child in children:
        if child.poll() is None:
            child.kill()
            child.wait()


def rising_edges(vcd_path, level="1"):
    """Rising edges (falling with level="0") per wire name of a sim-host VCD trace, in trace
    nanoseconds."""
    names, edges, now = {}, {}, 0
    with open(vcd_path) as f:
        for line in f:
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "$var" and len(parts) >= 5:
                names[parts[3]] = parts[4]
            elif line.startswith("#"):
                now = int(line[1:])
            elif line[0] == level and line[1:].strip() in names:
                edges.setdefault(names[line[1:].strip()], []).append(now)
    return edges


def wait_for_line(process: subprocess.Popen, text: str, timeout: float = 20.0) -> str:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        line = process.stdout.readline()
        if text in line:
            return line
        if not line and process.poll() is not None:
            break
    raise AssertionError(f"no line with {text!r}: {process.stderr.read() if process.poll() is not None else ''}")
