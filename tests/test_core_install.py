"""Installing a rebuilt core must not crash percver processes that have the old one loaded.

Regression: an F1/10 `estimate` run printed its result and then died with SIGSEGV (exit 139)
because the core was rebuilt meanwhile and `cp` overwrote the mapped _core.abi3.so in place.
"""

import subprocess
import sys
from pathlib import Path

import percver._core

SCRIPT = Path(__file__).resolve().parents[1] / ".ci" / "install-core"

# Loads the core from its own path (not via percver), keeps a core object alive, waits until the
# library has been replaced, then calls into the core again and exits (which frees the object).
CHILD = """
import importlib.util, sys
spec = importlib.util.spec_from_file_location("_core", sys.argv[1])
core = importlib.util.module_from_spec(spec)
spec.loader.exec_module(core)
kept = core.Interval(0.0, 1.0)
print("loaded", flush=True)
sys.stdin.readline()
print(core.Interval(2.0, 3.0), kept, flush=True)
"""


def test_install_replaces_a_loaded_core_without_crashing_its_users(tmp_path):
    source = Path(percver._core.__file__)
    dest = tmp_path / "_core.abi3.so"
    dest.write_bytes(source.read_bytes())
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(dest)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert child.stdout.readline().strip() == "loaded", child.stderr.read()
        before = dest.stat().st_ino
        subprocess.run(["bash", str(SCRIPT), str(source), str(dest)], check=True, timeout=60)
        out, err = child.communicate("go\n", timeout=60)
    finally:
        child.kill()
    assert child.returncode == 0, f"exit {child.returncode}: {err}"
    assert "Interval(2.0, 3.0)" in out
    assert dest.stat().st_ino != before and dest.read_bytes() == source.read_bytes()
    assert [p.name for p in tmp_path.iterdir()] == [dest.name]  # no temporary file left behind


def test_install_refuses_a_missing_library(tmp_path):
    dest = tmp_path / "_core.abi3.so"
    dest.write_bytes(b"old")
    run = subprocess.run(["bash", str(SCRIPT), str(tmp_path / "missing.so"), str(dest)], capture_output=True, text=True)
    assert run.returncode == 2 and "usage" in run.stderr
    assert dest.read_bytes() == b"old"
