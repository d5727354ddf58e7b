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


def test_demo_verifies_a_slice_with_the_shipped_networks(tmp_path):
    """The demo on a two-cell slice (the default slice is the same computation, 60 cells)."""
    out = tmp_path / "demo.png"
    r = run("demo", "--out", str(out), "--p0", "-0.5", "-0.4995", "--delta-c", "1.5", "1.6", "--no-progress", "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout.strip().splitlines()[-1])
    assert doc["verdict"] == "verified" and doc["row"]["coverage"] == 1.0
    assert doc["init"]["p"] == [-0.5, -0.4995] and doc["init"]["dc"] == [1.5, 1.6]
    assert doc["row"]["intervals"] == 2 and doc["row"]["avg_seconds"] > 0
    assert out.stat().st_size > 5000
    assert doc["domain_exits"] == [] and "DomainWarning" not in r.stderr


def test_demo_warns_outside_the_training_range_of_the_contrast_model(tmp_path):
    # the shipped contrast model was trained on contrast in [0.3, 2]: a proof at 0.05 is about its extrapolation
    r = run("demo", "--out", str(tmp_path / "demo.png"), "--p0", "-0.5", "-0.4995", "--delta-c", "0.05", "0.06", "--no-progress", "--json")
    assert r.returncode == 0, r.stderr
    assert "DomainWarning: stage 'image_dc' (network 'contrast'): dc in [0.05, 0.06] at step 0" in r.stderr
    (exit_,) = json.loads(r.stdout.strip().splitlines()[-1])["domain_exits"]
    assert exit_["input"] == "dc" and exit_["domain"] == [0.3, 2.0]
