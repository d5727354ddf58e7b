"""Camera validation on images with hidden effects (PIL contrast, the paper's blur, glare, misalignment)."""

import functools
from pathlib import Path

import numpy as np
import pytest

import hidden_world
import percver as pv
from percver.errors import InputError
from percver.sensors.camera import ImageModel

POSITIONS = np.random.default_rng(3).uniform(-1.2, 0.6, (120, 1))


def _camera():
    return ImageModel(hidden_world.render, ["p"], (hidden_world.H, hidden_world.WIDTH))


def _data(**hidden):
    return pv.Measurements(POSITIONS, hidden_world.images(POSITIONS, seed=4, **hidden), state_names=["p"])


@functools.lru_cache(maxsize=None)
def _diagnosis(**hidden):
    return pv.diagnose(_camera(), _data(**hidden))


def _params(diagnosis, name):
    return next(e for e in diagnosis.final_model.effects if e.name == name).params


SINGLE = [
    ({"contrast": 0.5}, "contrast", {"factor": (0.5, 0.03)}),
    ({"blur": 0.1}, "blur", {"delta": (0.1, 0.01)}),
    ({"glare": (4, 22, 3)}, "glare", {"row": (4, 0.5), "col": (22, 0.5), "radius": (3, 0.5)}),
    ({"shift_cols": 1}, "shift", {"cols": (1.0, 0.05), "rows": (0.0, 0.05)}),
]


@pytest.mark.parametrize("hidden, name, expected", SINGLE, ids=[s[1] for s in SINGLE])
def test_single_effect_is_named_and_recovered(hidden, name, expected):
    diagnosis = _diagnosis(**hidden)
    assert diagnosis.effects == [name]
    params = _params(diagnosis, name)
    for key, (value, tolerance) in expected.items():
        assert params[key] == pytest.approx(value, abs=tolerance), key
    assert diagnosis.final_error <= 0.2 * diagnosis.baseline_error


def test_contrast_and_blur_together():
    diagnosis = _diagnosis(contrast=1.5, blur=0.1)
    assert sorted(diagnosis.effects[:2]) == ["blur", "contrast"]
    assert _params(diagnosis, "contrast")["factor"] == pytest.approx(1.5, abs=0.05)
    assert _params(diagnosis, "blur")["delta"] == pytest.approx(0.1, abs=0.01)
    # Lighting acts before motion blur whatever order the effects were found in.
    assert [e.name for e in diagnosis.final_model.effects][:2] == ["contrast", "blur"]
    assert diagnosis.final_error <= 0.2 * diagnosis.baseline_error


def test_clean_images_claim_nothing():
    diagnosis = _diagnosis()
    assert diagnosis.steps == []
    assert diagnosis.unexplained == []


def test_state_estimation_metric_falls_with_the_effect():
    def estimator(images):
        """Position from the brightest column, as a downstream state estimator would."""
        column = np.argmax(images.reshape(len(images), hidden_world.H, hidden_world.WIDTH).max(axis=1), axis=1)
        return (column - 2) / (hidden_world.WIDTH - 5) * 1.8 - 1.2

    data = _data(shift_cols=2)
    before = pv.compare(_camera(), data, estimator=estimator)
    after = pv.compare(_camera().with_effect(pv.validate.effects.get("shift", cols=2.0)), data, estimator=estimator)
    assert after.downstream["estimation_error"] < 0.2 * before.downstream["estimation_error"]
    assert before.downstream["estimation_error"] > 0.1


def test_camera_model_checks_its_arguments():
    with pytest.raises(InputError, match="height, width"):
        ImageModel(hidden_world.render, ["p"], (600,))
    with pytest.raises(InputError, match="position 'q'"):
        ImageModel(hidden_world.render, ["p"], (20, 30), position="q")
    with pytest.raises(pv.MeasurementError, match="measurement columns"):
        pv.compare(_camera(), pv.Measurements(POSITIONS, np.zeros((120, 10)), state_names=["p"]))


def test_a_generator_network_is_an_image_model():
    """The shipped Mountain Car generator (p -> image) stands in for the renderer; the blur it
    misses is found by evaluating the network at the shifted positions."""
    from percver.cases import mountain_car as mc

    generator = ImageModel(pv.load_network(Path(mc.__file__).parent / "data" / "generator.onnx"), ["p"], mc.SHAPE)
    positions = np.random.default_rng(2).uniform(-1.2, 0.6, (40, 1))
    canonical = pv.Measurements(positions, mc.render(positions[:, 0]).reshape(40, -1), state_names=["p"])
    assert pv.compare(generator, canonical).mae < 0.01  # 0.0039 measured: the network's own error
    images = hidden_world.blurred(lambda states: mc.render(states[:, 0]), positions, 0.1).reshape(40, -1)
    diagnosis = pv.diagnose(generator, pv.Measurements(positions, images, state_names=["p"]), ["blur", "contrast"])
    assert diagnosis.effects == ["blur"]
    assert _params(diagnosis, "blur")["delta"] == pytest.approx(0.1, abs=0.005)  # 0.1003 measured
