"""Mountain Car dynamics, the network sets, and the paper's state-estimation metric on the authors' networks."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import percver as pv
from percver.cases import mountain_car as mc
from percver.errors import InputError, MissingFileError

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="module")
def paper():
    # No skip: these tests exist to check the pipeline against the authors' networks.
    assert (SHARED / "mountain_car" / "networks").is_dir(), f"the shared data is missing: {SHARED}"
    return mc.load("paper", shared=SHARED)


@pytest.fixture(scope="module")
def evaluation(paper):
    return mc.evaluate(paper, trajectories=6, seed=3, progress=False)


def test_dynamics_reproduce_the_state_based_sanity_values(paper):
    """p0 = -0.5 reaches the goal at step 92 with reward 92.58; p0 = -0.6 does not within 150 steps."""
    runs = mc.simulate([-0.5, -0.6], lambda k, p, v, active: paper.control(p, v))
    assert runs.reached_at.tolist() == [92, -1]
    assert runs.reward[0] == pytest.approx(92.58, abs=0.005)
    assert runs.safe.tolist() == [True, False]


def test_step_is_the_expression():
    p, v = mc.step([-0.5, -1.19], [0.01, -0.05], [1.0, -1.0])
    v_next = np.clip(0.01 + 0.0015 - 0.0025 * np.cos(-1.5), -0.07, 0.07)
    assert v[0] == pytest.approx(v_next) and p[0] == pytest.approx(-0.5 + v_next)
    assert (p[1], v[1]) == (-1.2, 0.0)  # stopped at the left wall


def test_paper_networks_load_with_the_estimate_map(paper):
    assert paper.contrast.n_in == paper.blur.n_in == 601
    raw = pv.load_network(mc.paper_dir(SHARED) / mc.networks.PAPER_FILES["estimator"])
    images = mc.render([-0.5, 0.0])
    np.testing.assert_allclose(paper.estimate(images), 0.9 * raw(images.reshape(2, 600))[:, 0] - 0.3)
    np.testing.assert_allclose(paper.estimate(images), [-0.5, 0.0], atol=0.06)


def test_paper_networks_missing_is_an_error(tmp_path):
    with pytest.raises(MissingFileError, match="pass shared=PATH"):
        mc.load("paper", shared=tmp_path)
    with pytest.raises(MissingFileError, match="neither 'paper', 'ours' nor"):
        mc.load(str(tmp_path / "nowhere"))


def test_metric_is_the_estimate_difference(paper, evaluation):
    runs = evaluation.runs["blur"]
    i, k = 0, 5
    p = runs.trajectories.p[i, k]
    delta = runs.params["delta_b"][i]
    true = paper.estimate(mc.observe([p], delta_b=delta))[0]
    model = paper.estimate(paper.images([p], delta_b=delta))[0]
    assert runs.p_hat_true[i, k] == pytest.approx(true)
    assert runs.p_hat_model[i, k] == pytest.approx(model)
    assert runs.errors.size == runs.trajectories.active.sum()


def test_metric_on_the_authors_networks(evaluation):
    """Our images with the authors' models: errors of the order the paper reports (blur <= 0.09 there;
    their blur model is less exact on our renderer at the largest blur)."""
    summary = evaluation.summary()
    noises = summary["noises"]
    assert set(noises) == {"canonical", "contrast", "blur", "composite"}
    for name, limit in {"canonical": 0.08, "contrast": 0.1, "blur": 0.2, "composite": 0.2}.items():
        assert noises[name]["max"] < limit, name
        assert noises[name]["mean"] < 0.05, name
        assert noises[name]["p95"] <= noises[name]["max"]
        assert noises[name]["closed_loop_safe_fraction"] > 0.9, name
    assert noises["blur"]["paper_bound"] == summary["paper"]["blur"]["max"] == 0.09
    assert "paper max" in evaluation.table()


def test_plots_and_summary(evaluation, tmp_path):
    pytest.importorskip("matplotlib")
    paths = evaluation.plot(tmp_path)
    assert {p.name for p in paths} == {
        "trajectories_canonical.png", "trajectories_contrast.png", "trajectories_blur.png",
        "trajectories_composite.png", "figure4.png", "histograms.png",
    }  # fmt: skip
    assert all(p.stat().st_size > 10_000 for p in paths)
    saved = json.loads(evaluation.to_json(tmp_path / "s.json").read_text())
    assert saved["noises"]["contrast"]["trajectories"] == 6


def test_evaluate_checks_its_arguments():
    with pytest.raises(InputError, match="unknown noise"):
        mc.evaluate("ours", noises=["fog"], progress=False)
    with pytest.raises(InputError, match="at least 1"):
        mc.evaluate("ours", trajectories=0, progress=False)


def test_cli_evaluate_ours_with_the_paper_controller(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "percver.cli", "cases", "mountain-car", "evaluate", "--networks", "ours",
         "--controller", "paper", "--shared", str(SHARED), "--noises", "contrast", "--trajectories", "2", "--steps", "30",
         "--out", str(tmp_path), "--no-plots", "--json"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    result = json.loads(done.stdout)
    assert result["noises"]["contrast"]["trajectories"] == 2
    assert (tmp_path / "summary.json").is_file()
    missing = subprocess.run(
        [sys.executable, "-m", "percver.cli", "cases", "mountain-car", "train", "--data", str(tmp_path / "none.npz")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert missing.returncode == 1 and "data set not found" in missing.stderr
