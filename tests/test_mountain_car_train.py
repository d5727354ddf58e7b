"""Reduced training runs of the Mountain Car models, ONNX round trips, and the shipped networks."""

import json
from pathlib import Path

import numpy as np
import onnxruntime
import pytest

torch = pytest.importorskip("torch")

import percver as pv  # noqa: E402
from percver.cases import mountain_car as mc  # noqa: E402
from percver.cases.mountain_car import dynamics, training  # noqa: E402
from percver.errors import InputError  # noqa: E402

PACKAGED = Path(mc.__file__).parent / "data"


# Reduced runs on 60 positions: small batches and more epochs than the full presets, which see
# 30x more data per epoch.
REDUCED = {
    "generator": {"epochs": 400, "batch": 16, "lr": 1e-2},
    "contrast": {"epochs": 300, "batch": 16, "lr": 1e-2},
    "blur": {"epochs": 300, "batch": 16, "lr": 1e-2},
    "estimator": {"epochs": 60, "batch": 32, "lr": 5e-3},
    "controller": {"epochs": 30},
}


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """Three runs into one directory, as a user retrains a subset: generator; noise models and
    estimator (its composites made by those noise models); controller. Sizes of the "small" preset."""
    data = mc.generate(60, 4, seed=0, progress=False)
    out = tmp_path_factory.mktemp("mc-networks")
    runs = [
        mc.train(data, out, preset="small", models=["generator"], overrides=REDUCED, progress=False),
        mc.train(data, out, preset="small", models=["contrast", "blur", "estimator"], overrides=REDUCED,
                 composites=540, seed=1, progress=False),
        mc.train(data, out, preset="small", models=["controller"], overrides=REDUCED, progress=False),
    ]  # fmt: skip
    fits = {role: fit for run in runs for role, fit in run.fits.items()}
    return data, out, fits


def test_reduced_training_reaches_stated_losses(trained):
    _, _, fits = trained
    # Held-out pixel MSE; predicting the mean image scores 0.030 (canonical), 0.031 (contrast), 0.024 (blur),
    # returning the canonical image unchanged 0.0040 (contrast) and 0.0039 (blur).
    assert fits["generator"].test_metric < 0.008
    assert fits["contrast"].test_metric < 0.005
    assert fits["blur"].test_metric < 0.004
    assert fits["estimator"].test_metric < 0.04  # mean |p_hat - p| on held-out positions; the mean position scores 0.46
    assert fits["controller"].test_loss < 0.06  # squared error to the pumping policy
    assert fits["controller"].test_metric > 90  # least reward in closed loop, p0 in [-0.6, -0.4], p noise +-0.05
    for fit in fits.values():
        assert np.isfinite(fit.train_loss) and fit.seconds > 0


@pytest.mark.parametrize("role", ["generator", "contrast", "blur", "estimator", "controller"])
def test_onnx_round_trip(trained, role):
    _, out, fits = trained
    model = fits[role].model
    path = out / f"{role}.onnx"
    network = pv.load_network(path)
    assert network.domain == tuple(mc.networks.training_domain(role))  # written on export, read back
    n_in = network.n_in
    x = np.random.default_rng(1).uniform(0, 1, (16, n_in))
    x[:, -1] = np.linspace(-0.6, 0.6, 16) if role != "controller" else np.linspace(-0.07, 0.07, 16)
    with torch.no_grad():
        expected = model(torch.as_tensor(x, dtype=torch.float32)).double().numpy()
    np.testing.assert_allclose(network(x), expected, atol=1e-5)
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    (output,) = session.run(None, {session.get_inputs()[0].name: x.astype(np.float32)})  # float32 files
    np.testing.assert_allclose(output, expected, atol=1e-5)


def test_estimator_exports_the_position_map(trained):
    _, out, _ = trained
    estimator = pv.load_network(out / "estimator.onnx")
    assert estimator.scale == pytest.approx([0.9]) and estimator.offset == pytest.approx([-0.3])
    assert estimator.layers[-1].activation == "tanh" and len(estimator.layers) == 4


def test_networks_json_records_every_run(trained):
    data, out, fits = trained
    record = json.loads((out / "networks.json").read_text())
    assert len(record["runs"]) == 3
    assert record["runs"][1]["seed"] == 1 and record["runs"][1]["dataset"]["n_positions"] == 60
    assert record["models"]["generator"]["run"] == 0 and record["models"]["blur"]["run"] == 1
    assert record["models"]["contrast"]["hidden"] == [32]
    assert "percver.cases.mountain_car.train" in record["runs"][0]["command"]
    chain = mc.load(out)
    assert chain.estimate(chain.images([-0.5], delta_c=1.0)).shape == (1,)


def test_training_checks_its_arguments(trained, tmp_path):
    data, _, _ = trained
    with pytest.raises(InputError, match="unknown preset"):
        mc.train(data, tmp_path, preset="huge")
    with pytest.raises(InputError, match="unknown model"):
        mc.train(data, tmp_path, models=["decoder"])
    with pytest.raises(InputError, match="overrides: 'blur'"):
        mc.train(data, tmp_path, overrides={"blur": {"width": 3}})
    with pytest.raises(InputError, match="contrast model, but .* does not exist"):
        mc.train(data, tmp_path, models=["estimator"], progress=False)


def test_pumping_policy_meets_the_property():
    p0 = np.linspace(-0.6, -0.4, 41)
    runs = dynamics.simulate(p0, lambda k, p, v, active: training.pump(p, v))
    assert runs.safe.all() and runs.reward.min() > 92.8


def test_shipped_networks():
    record = mc.networks.provenance("ours")
    assert mc.networks.provenance("paper") == {}
    assert {"generator", "contrast", "blur", "estimator", "controller"} <= set(record["models"])
    assert all("command" in run and "seed" in run for run in record["runs"])
    size = sum(path.stat().st_size for path in PACKAGED.glob("*.onnx"))
    assert size < 700_000  # float32 ONNX with their training domains, 654 KB
    ours = mc.load("ours")
    assert ours.source == PACKAGED
    for role in mc.networks.ROLES:  # verify warns where a set leaves them
        assert getattr(ours, role).domain == tuple(mc.networks.training_domain(role))
    check = training.controller_check(ours.controller, noise=0.05)
    assert check["safe_fraction"] == 1.0 and check["min_reward"] > 90


def test_controller_from_another_set():
    chain = mc.load("ours", controller=PACKAGED / "controller.onnx")
    assert chain.controller.n_in == 2
    with pytest.raises(InputError, match="roles are"):
        chain.with_networks(decoder=chain.generator)
    with pytest.raises(InputError, match="needs 2 -> 1"):
        chain.with_networks(controller=chain.estimator)
