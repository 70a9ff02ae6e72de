"""Issue 23: the README's Python snippet type-checks (mypy, against armctl.pyi) and runs,
twice in a row, against sim-host (it used to fail the second time: its trajectory starts at
0 and the arm was left at 800)."""

import os
import pathlib
import re
import subprocess
import sys

import pytest

from conftest import CHILD_CWD

README = pathlib.Path(__file__).resolve().parents[1] / "README.md"
STUBS = pathlib.Path(__file__).resolve().parents[1]


def snippets():
    return re.findall(r"```python\n(.*?)```", README.read_text(), re.S)


def test_the_readme_has_a_snippet():
    assert snippets(), "README.md has no ```python block"


def test_mypy_accepts_the_readme_snippets(tmp_path):
    mypy = pytest.importorskip("mypy.api", reason="needs mypy (pip install mypy; .ci/run installs it)")
    for i, code in enumerate(snippets()):
        path = tmp_path / f"snippet_{i}.py"
        path.write_text(code)
        # The stubs as the installed package ships them, from the source tree.
        out, err, status = mypy.run([
            "--strict", "--no-incremental", "--cache-dir", os.devnull,
            "--python-executable", sys.executable, str(path),
        ])
        assert status == 0, f"snippet {i}:\n{code}\n{out}{err}"


def test_the_readme_snippet_runs_twice(sim):
    code = snippets()[0].replace('"127.0.0.1:8510"', repr(sim.address))
    for run in range(2):
        child = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                               timeout=120, cwd=CHILD_CWD)
        assert child.returncode == 0, f"run {run + 1}:\n{child.stdout}{child.stderr}"
        assert "[0 0 0 0 0 0]" in child.stdout, child.stdout
