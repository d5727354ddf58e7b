"""The percver command: help, the demo job, and errors as one line with a non-zero exit."""

import json
import subprocess
import sys


def run(*args):
    return subprocess.run([sys.executable, "-m", "percver.cli", *args], capture_output=True, text=True, timeout=300)


def test_help_lists_commands():
    r = run("--help")
    assert r.returncode == 0
    assert "demo" in r.stdout


def test_demo_writes_plot_and_final_box(tmp_path):
    out = tmp_path / "demo.png"
    r = run("demo", "--out", str(out), "--no-progress", "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout.strip().splitlines()[-1])
    assert set(doc["final_box"]) == {"x", "y"}
    assert out.stat().st_size > 5000
    # The Van der Pol set returns near its start after one period (about 6.7 time units).
    lo, hi = doc["final_box"]["x"]
    assert -3 < lo < hi < 3
