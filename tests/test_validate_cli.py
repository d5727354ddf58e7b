"""``percver validate``: tables, the HTML report, JSON, and one-line errors with a non-zero exit."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np

import hidden_world
import percver as pv

TESTS = Path(__file__).parent


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "percver.cli", "validate", *args], capture_output=True, text=True,
                          timeout=300, cwd=cwd)


def test_lidar_run_prints_steps_and_writes_the_report(tmp_path):
    poses = hidden_world.poses(300, seed=7)
    scans = hidden_world.scan(poses, seed=8, bias=0.1)
    pv.Measurements(poses, scans, state_names=["x", "y", "theta"]).save(tmp_path / "scans.npz")
    r = run("--model", "lidar-f1tenth", "--data", str(tmp_path / "scans.npz"), "--out", str(tmp_path / "report"),
            "--no-progress")
    assert r.returncode == 0, r.stderr
    assert "step 1: + range_bias" in r.stdout
    assert "claimed" in r.stdout  # the ranked table
    assert (tmp_path / "report" / "index.html").exists()
    assert (tmp_path / "report" / "error_fall.png").exists()


def test_plant_from_a_python_file_with_json_output(tmp_path):
    states, controls, trajectory, time = hidden_world.runs(10, 40, seed=9, drag=0.03)
    pv.Measurements(states, controls=controls, trajectory=trajectory, time=time, state_names=["p", "v"],
                    control_names=["u"]).save(tmp_path / "runs.parquet")
    (tmp_path / "plant.py").write_text(
        "import sys\n"
        f"sys.path.insert(0, {str(TESTS)!r})\n"
        "import hidden_world\n"
        "from percver.validate import FunctionPlant\n"
        "plant = FunctionPlant(hidden_world.mountain_car_step, ['p', 'v'], ['u'])\n"
    )
    r = run("--model", "plant.py:plant", "--data", "runs.parquet", "--out", "report", "--json",
            "--effects", "linear_drag,actuator_gain", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert [s["effect"] for s in doc["steps"]] == ["linear_drag"]
    assert abs(doc["steps"][0]["params"]["coefficient"] - 0.03) < 0.003
    assert Path(doc["report"]).exists()


def test_bad_input_exits_non_zero_with_one_line(tmp_path):
    states = hidden_world.poses(20, seed=1)
    scans = hidden_world.scan(states)
    scans[5, 3] = np.nan
    np.savez(tmp_path / "bad.npz", states=states, measurements=scans)
    r = run("--model", "lidar-f1tenth", "--data", str(tmp_path / "bad.npz"))
    assert r.returncode == 1
    assert r.stderr.count("\n") == 1 and "row 5" in r.stderr and "dropna" in r.stderr
    r = run("--model", "nonsense", "--data", str(tmp_path / "bad.npz"))
    assert r.returncode == 1 and "FILE.py:NAME" in r.stderr
    r = run("--model", "lidar-f1tenth", "--data", str(tmp_path / "missing.npz"))
    assert r.returncode == 1 and "does not exist" in r.stderr
