"""`percver cases f1tenth simulate|estimate|label|train|evaluate` end to end on a few runs."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

import percver as pv
from percver.cli import main

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "f1tenth"
torch.set_num_threads(2)


def run(capsys, *argv):
    assert main(["cases", "f1tenth", *argv, "--json"]) == 0
    return json.loads(capsys.readouterr().out)


def test_pipeline_end_to_end(tmp_path, capsys):
    runs, training, labels, models = (tmp_path / n for n in ("runs.npz", "training.npz", "labels.npz", "models"))
    simulated = run(
        capsys, "simulate", "--out", str(runs), "--runs", "1", "--controllers", "TD3_L21_64x64_C2,DDPG_L21_64x64_C1", "--data", str(DATA)
    )
    assert simulated["calibration"]["runs"] == 2 and simulated["calibration"]["real"]["crashes"] == 45
    estimated = run(capsys, "estimate", "--runs", str(runs), "--out", str(training), "--particles", "100")
    assert estimated["pose_error"]["after_1s"]["position_median_m"] < 0.1
    data = pv.Measurements.load(training)
    assert data.state_names == ("x", "y", "theta") and data.measurements.shape[1] == 21
    labelled = run(capsys, "label", "--training", str(training), "--out", str(labels), "--plot", str(tmp_path / "curve.png"))
    assert 0.0 < labelled["t_delta"] < 5.0 and (tmp_path / "curve.png").is_file()
    assert 0.0 < labelled["label_ceiling"]["ceiling"] <= 1.0
    trained = run(
        capsys,
        "train",
        "--training",
        str(training),
        "--labels",
        str(labels),
        "--out",
        str(models),
        "--sizes",
        "3x100",
        "--epochs",
        "2",
        "--denoiser-epochs",
        "2",
        "--threads",
        "2",
        "--data",
        str(DATA),
    )
    assert set(trained["classifiers"]) == {"3x100"}
    assert (models / "noiser3x100.onnx").is_file() and (models / "thresholds3x100.npy").is_file()
    network = pv.load_network(models / "denoiser.onnx")
    assert (network.n_in, network.n_out) == (21, 21)
    ours = run(
        capsys,
        "evaluate",
        "--training",
        str(training),
        "--labels",
        str(labels),
        "--models",
        str(models),
        "--out",
        str(tmp_path / "eval"),
        "--plot-size",
        "3x100",
        "--data",
        str(DATA),
    )
    row = ours["noise_models"]["3x100"]
    assert 0.0 <= row["whole_scan_accuracy"] <= 1.0 and set(row["trajectory"]) == {"TD3_L21_64x64_C2", "DDPG_L21_64x64_C1"}
    assert all(Path(f).is_file() for f in ours["figures"])
    paper = run(
        capsys,
        "evaluate",
        "--training",
        str(training),
        "--labels",
        str(labels),
        "--models",
        "paper",
        "--out",
        str(tmp_path / "eval_paper"),
        "--no-plots",
        "--data",
        str(DATA),
    )
    assert set(paper["noise_models"]) == {"5x100"} and "denoiser" in paper


def test_errors_name_the_file_and_the_fix(tmp_path, capsys):
    assert main(["cases", "f1tenth", "estimate", "--runs", str(tmp_path / "missing.npz")]) == 1
    assert "does not exist" in capsys.readouterr().err
    np.savez(tmp_path / "labels.npz", labels=np.zeros((3, 21)))
    pv.Measurements(
        np.zeros((3, 3)),
        np.zeros((3, 21)),
        trajectory=[0, 0, 0],
        time=[0, 1, 2],
        state_names=("x", "y", "theta"),
        meta={"runs": [{"controller": "TD3_L21_64x64_C2", "crashed": False}]},
    ).save(tmp_path / "training.npz")
    assert (
        main(
            [
                "cases",
                "f1tenth",
                "train",
                "--training",
                str(tmp_path / "training.npz"),
                "--labels",
                str(tmp_path / "labels.npz"),
                "--data",
                str(DATA),
            ]
        )
        == 1
    )
    assert "percver cases f1tenth label" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["cases", "f1tenth", "train", "--help"])
