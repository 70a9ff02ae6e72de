"""Issue 31: the Python tests do not depend on the working directory. From the repository
root, `import armctl` in a Python without the package found the Rust crate's folder
`armctl/` (a namespace package: "module 'armctl' has no attribute 'connect'" in every
test); conftest now stops at once and says what to do."""

import os
import pathlib
import subprocess
import sys

import pytest

from conftest import ROOT

TESTS = pathlib.Path(__file__).resolve().parent

# A child Python started from the repository root whose package is hidden (the sys.path
# entry that holds it dropped after pytest was loaded from it), which then loads conftest
# as pytest would.
WITHOUT_THE_PACKAGE = r"""
import os, sys
import pytest
import armctl as installed
where = os.path.dirname(os.path.dirname(os.path.abspath(installed.__file__)))
for name in [m for m in sys.modules if m == "armctl" or m.startswith("armctl.")]:
    del sys.modules[name]
sys.path[:] = [p for p in sys.path if os.path.abspath(p or ".") != where]
sys.path.insert(0, sys.argv[1])
try:
    import conftest
except BaseException as e:
    print(type(e).__name__, e)
else:
    import armctl
    print("imported", getattr(armctl, "__path__", armctl), "connect" in dir(armctl))
"""


def test_without_the_package_the_tests_stop_and_say_what_to_do():
    child = subprocess.run([sys.executable, "-c", WITHOUT_THE_PACKAGE, str(TESTS)], cwd=ROOT,
                           capture_output=True, text=True, timeout=60)
    out = child.stdout + child.stderr
    assert "not the armctl Python package" in out, out
    assert "pip install ./armctl-py" in out, out
    assert str(ROOT / "armctl") in out, out


@pytest.mark.parametrize("cwd", [ROOT, ROOT / "armctl", pathlib.Path(os.sep)], ids=str)
def test_the_tests_run_from_any_directory(cwd):
    # The fastest tests that import armctl and start a child Python from conftest.
    child = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
         str(TESTS / "test_readme.py"), "-k", "has_a_snippet or runs_twice"],
        cwd=cwd, capture_output=True, text=True, timeout=300)
    assert child.returncode == 0, child.stdout + child.stderr
    assert "2 passed" in child.stdout, child.stdout
