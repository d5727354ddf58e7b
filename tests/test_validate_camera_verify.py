"""A diagnosed camera is verified: its renderer (pixel expressions or a generator network) and
every fitted effect as expressions, judged against a camera of our own with a hidden lighting
effect (a 3 x 8 picture of a blob at the car's position) that percver does not know."""

import functools

import numpy as np
import onnxruntime
import pytest

import percver as pv
from percver.expr import held_parameters
from percver.networks import Layer, Network
from percver.sensors.camera import ImageModel
from percver.validate import verifiable
from percver.validate.effects import get
from percver.validate.effects.camera import ImageEffect

H, W = 3, 8
CENTRES = np.linspace(-1.0, 1.0, W)
ROWS = np.array([0.5, 1.0, 0.5])
WIDTH = 0.35
CONTRAST = 0.6  # the hidden camera's lighting
NOISE = 0.005  # its pixel noise, uniform in [-NOISE, NOISE]
p, v, u, p_hat = pv.variables("p v u p_hat")


def render(states):
    """The true scene: a blob over the columns at position p (states[:, 0]), brightest in the middle row."""
    at = np.asarray(states, dtype=float)[:, :1]
    return (ROWS[None, :, None] * np.exp(-(((at[:, None, :] - CENTRES) / WIDTH) ** 2))).reshape(len(at), -1)


def pixel_exprs():
    return [ROWS[r] * pv.exp(-(((p - CENTRES[c]) / WIDTH) ** 2)) for r in range(H) for c in range(W)]


def hidden_camera(states, rng):
    """What the real camera sees: the scene under low contrast about its mean grey, plus noise."""
    images = render(states)
    mean = images.mean(axis=1, keepdims=True)
    images = np.clip(mean + CONTRAST * (images - mean), 0.0, 1.0)
    return np.clip(images + rng.uniform(-NOISE, NOISE, images.shape), 0.0, 1.0)


@functools.lru_cache(maxsize=None)
def generator() -> Network:
    """A generator network of the scene (24 tanh features, output layer by least squares)."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(0.0, 3.0, 24), rng.uniform(-3.0, 3.0, 24)
    at = np.linspace(-1.4, 1.4, 2000)[:, None]
    features = np.column_stack([np.tanh(at * a + b), np.ones(len(at))])
    coef = np.linalg.lstsq(features, render(at), rcond=None)[0]
    return Network([Layer(a[:, None], b, "tanh"), Layer(coef[:-1].T, coef[-1], "identity")], name="generator")


@functools.lru_cache(maxsize=None)
def estimator() -> Network:
    """Position from the canonical image, linear by least squares (what the controller was designed with)."""
    at = np.linspace(-1.2, 1.2, 500)[:, None]
    coef = np.linalg.lstsq(np.column_stack([render(at), np.ones(len(at))]), at[:, 0], rcond=None)[0]
    return Network([Layer(coef[None, :-1], coef[-1:], "identity")], name="estimator")


PLANT = pv.Discrete({p: p + 0.1 * v, v: v + 0.1 * u}, inputs=[u])
CONTROL = pv.clip(-1.0 * p_hat - 1.5 * v, -1.0, 1.0)


def loop(camera_stages) -> pv.ClosedLoop:
    perception = pv.Perception(
        canonical=camera_stages[0],
        noiser=camera_stages[1:],
        estimator=pv.Stage(estimator(), inputs=["image"], output="p_hat"),
        controller=pv.Stage(CONTROL, inputs=[p_hat, v], output="u"),
    )
    return pv.ClosedLoop(PLANT, perception)


@functools.lru_cache(maxsize=None)
def diagnosis():
    rng = np.random.default_rng(1)
    states = rng.uniform(-1.2, 1.2, (400, 1))
    data = pv.Measurements(states, hidden_camera(states, rng), state_names=["p"])
    return pv.diagnose(ImageModel(generator(), ["p"], (H, W)), data)


def test_a_hidden_contrast_is_found_and_the_diagnosed_camera_is_verified_on_its_runs(tmp_path):
    found = diagnosis()
    assert found.effects == ["contrast"]
    camera = found.system(uncertainty="ci95", residual="max", draws=20)
    assert isinstance(camera, verifiable.CameraSensor)
    (lo, hi) = camera.validation.effects[0]["params"]["factor"]
    assert lo <= CONTRAST <= hi and hi - lo < 0.01
    assert max(camera.validation.residual.values()) < 2 * NOISE
    init = {"p": (0.6, 0.7), "v": (0.0, 0.0)}
    # The controller brings the car to |p| <= 0.1 within 40 steps with the camera it was designed
    # for; under the real lighting its estimates lag, and the diagnosed camera shows it.
    goal = {"steps": 40, "goal": [p <= 0.1, p >= -0.1], "within": True, "progress": False}
    assert pv.verify(loop([pv.Stage(generator(), inputs=[p], output="image")]), init, **goal).verdict == "verified"
    diagnosed = loop(camera.stages("image"))
    falsified = pv.verify(diagnosed, init, **goal)
    assert falsified.verdict == "falsified" and "inside the validated domain" in falsified.validity
    cex = falsified.counterexample
    runs = real_runs(np.array([[cex.initial["p"], cex.initial["v"]]]), 40, tmp_path)
    assert np.all(runs[0, :, 0] > 0.1)  # the real camera's car misses the goal from there too
    # Safety with the diagnosed camera: verified, and the real camera's runs stay in the reach sets.
    steps = 20
    safe = pv.verify(diagnosed, init, steps=steps, safe=[p >= -0.2, p <= 0.8], progress=False)
    assert safe.verdict == "verified" and safe.states == ["p", "v", "param_0"]
    assert safe.validity.startswith(f"verified inside the validated domain ({found.domain.describe()})")
    rng = np.random.default_rng(5)
    x0 = np.column_stack([rng.uniform(0.6, 0.7, 300), np.zeros(300)])
    x0[:2, 0] = [0.6, 0.7]
    runs = real_runs(x0, steps, tmp_path)
    domain = found.domain.bounds["p"]
    assert np.all((runs[:, :, 0] >= domain[0]) & (runs[:, :, 0] <= domain[1]))  # every step is checked
    covered = np.zeros(len(x0), dtype=bool)
    for cell in safe.cells:
        # The engine splits the held contrast too: the real camera's runs belong to the cells holding its value.
        if not cell.box["param_0"][0] <= CONTRAST <= cell.box["param_0"][1]:
            continue
        inside = (x0[:, 0] >= cell.box["p"][0]) & (x0[:, 0] <= cell.box["p"][1])
        covered |= inside
        for t, box in enumerate(np.asarray(cell.boxes)):
            for j in range(2):
                part = runs[inside, t, j]
                assert np.all(part >= box[j, 0] - 1e-9) and np.all(part <= box[j, 1] + 1e-9), (t, j, box[j], part.min(), part.max())
    assert covered.all()


def real_runs(x0, steps, folder):
    """Runs of the loop with the real camera: numpy renders, the estimator by onnxruntime from
    its ONNX file, the controller and the car in numpy."""
    path = folder / "estimator.onnx"
    pv.save_network(estimator(), path)
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(9)
    out = np.empty((len(x0), steps + 1, 2))
    out[:, 0] = x = np.array(x0, dtype=float)
    for t in range(steps):
        images = hidden_camera(x[:, :1], rng)
        estimate = session.run(None, {session.get_inputs()[0].name: images})[0][:, 0]
        thrust = np.clip(-1.0 * estimate - 1.5 * x[:, 1], -1.0, 1.0)
        x = np.column_stack([x[:, 0] + 0.1 * x[:, 1], x[:, 1] + 0.1 * thrust])
        out[:, t + 1] = x
    return out


EFFECTS = [get("contrast", factor=1.3), get("blur", delta=0.1), get("shift", rows=0.4, cols=-1.3), get("glare", row=1, col=5, radius=1.2)]
RANGES = {0: {"factor": (1.2, 1.4)}, 1: {"delta": (0.08, 0.12)}, 2: {"rows": (0.2, 0.6), "cols": (-1.6, -0.9)}, 3: {"radius": (1.0, 1.5)}}


def _drawn(rng):
    """The effects with parameters drawn from RANGES."""
    return [effect.replace(**{k: rng.uniform(*pair) for k, pair in RANGES[i].items()}) for i, effect in enumerate(EFFECTS)]


def test_every_camera_effect_as_expressions_is_the_float_model_and_encloses_it_over_its_ranges():
    camera = ImageModel(pixel_exprs(), ["p"], (H, W)).with_effects(EFFECTS)
    states = np.random.default_rng(0).uniform(-1.0, 1.0, (60, 1))
    domain = verifiable.Domain.of(["p"], states)
    fitted = verifiable.camera_component(camera, {}, None, None, None, domain)
    np.testing.assert_allclose(pv.evaluate(list(fitted), {"p": states[:, 0]}), camera.predict(states), atol=1e-12)
    ranged = verifiable.camera_component(camera, RANGES, None, None, 0.95, domain)
    # factor, delta, rows, cols held over a run; the glare's radius only decides which pixels may be saturated.
    assert len(held_parameters(list(ranged))) == 4
    rng = np.random.default_rng(2)
    for lo in (-0.9, 0.1, 0.55):
        box = {"p": (lo, lo + 0.05)}
        bounds = np.array(pv.bounds(list(ranged), box, method="interval"))
        for _ in range(100):
            images = camera.with_effects(_drawn(rng)).predict(rng.uniform(lo, lo + 0.05, (10, 1)))
            assert np.all(images >= bounds[:, 0] - 1e-12) and np.all(images <= bounds[:, 1] + 1e-12)


def test_a_network_camera_with_blur_and_shift_is_a_chain_that_encloses_its_renders():
    """The blur renders the moved positions through the network too; one step of a loop whose plant
    keeps some pixels holds the float images for every drawn parameter (held over the run)."""
    camera = ImageModel(generator(), ["p"], (H, W)).with_effects(EFFECTS[:3])
    ranges = {i: RANGES[i] for i in range(3)}
    sensor = verifiable.camera_component(camera, ranges, None, None, 0.95, verifiable.Domain.of(["p"], np.zeros((1, 1))))
    chain = sensor.stages("image")
    assert [s.output for s in chain] == ["image_render0", "image_at1", "image_render1", "image_at2", "image_render2", "image"]
    kept = [3, 12, 13, 20]
    plant = pv.Discrete({p: p, **{f"y{k}": pv.Expr.var(f"image_{k}") for k in kept}})
    closed = pv.ClosedLoop(plant, chain)
    ids = {name: expr.parameters()[0][0] for _, params in sensor.effects for name, expr in params.items()}
    lo = 0.2
    init = {"p": (lo, lo + 0.05), **{f"y{k}": (0.0, 0.0) for k in kept}}
    result = pv.verify(closed, init, steps=1, safe=p <= 10.0, progress=False)
    assert result.verdict == "verified"
    rng = np.random.default_rng(3)
    n = 200
    x0 = np.column_stack([rng.uniform(lo, lo + 0.05, n), np.zeros((n, len(kept)))])
    drawn = [_drawn(rng)[:3] for _ in range(n)]
    values = {ids[k]: np.array([effects[i].params[k] for effects in drawn]) for i in range(3) for k in RANGES[i]}
    runs = closed.simulate(x0, 1, values)[:, 1, 1:]
    expected = np.array([camera.with_effects(effects).predict(x[None, :1])[0, kept] for effects, x in zip(drawn, x0)])
    np.testing.assert_allclose(runs, expected, atol=1e-9)  # the chain's floats are the camera model's
    held = closed.with_held_parameters().held  # param_k -> (id, lo, hi), as verify names them
    assert sorted(pid for pid, _, _ in held.values()) == sorted(values)
    for cell in result.cells:
        box = np.asarray(cell.boxes)[1][1 : 1 + len(kept)]
        inside = (x0[:, 0] >= cell.box["p"][0]) & (x0[:, 0] <= cell.box["p"][1])
        for name, (pid, _, _) in held.items():
            inside &= (values[pid] >= cell.box[name][0]) & (values[pid] <= cell.box[name][1])
        assert np.all(runs[inside] >= box[:, 0] - 1e-9) and np.all(runs[inside] <= box[:, 1] + 1e-9)


def test_cameras_without_a_set_form_are_refused_with_what_to_do():
    data = diagnosis()
    scene = ImageModel(render, ["p"], (H, W))
    with pytest.raises(verifiable.NoSetSemanticsError, match="Python function.*generator pv.Network.*expression per pixel"):
        verifiable.camera_component(scene, {}, None, None, None, data.domain)

    class Vignette(ImageEffect):
        name = "vignette"

        def apply(self, images, states, model, before):
            return images

    with pytest.raises(verifiable.NoSetSemanticsError, match="'vignette' has no expression form.*residual='max'"):
        verifiable.camera_component(ImageModel(pixel_exprs(), ["p"], (H, W)).with_effects([Vignette()]), {}, None, None, None, data.domain)
    noisy = ImageModel(pixel_exprs(), ["p"], (H, W)).with_effects([get("gaussian_noise", sigma=0.01)])
    with pytest.raises(verifiable.NoSetSemanticsError, match="gaussian_noise is unbounded"):
        verifiable.camera_component(noisy, {}, None, None, None, data.domain)
    with pytest.raises(pv.InputError, match="takes 1 inputs; it must take the camera's states"):
        ImageModel(generator(), ["p", "v"], (H, W))
    with pytest.raises(pv.InputError, match="gives 24 pixels, its shape 30"):
        ImageModel(pixel_exprs(), ["p"], (5, 6))


def test_a_learned_noise_model_after_a_network_camera_follows_its_chain():
    """A shadow no library effect explains is learned (generative, the paper's g_n); its network
    stage reads the generator's render, and the chain's floats are the diagnosed model's."""
    pytest.importorskip("torch")
    rng = np.random.default_rng(4)
    states = rng.uniform(-1.2, 1.2, (400, 1))
    shadowed = np.where(states > 0.3, 0.6, 1.0) * render(states) + rng.uniform(-NOISE, NOISE, (400, H * W))
    data = pv.Measurements(states, shadowed, state_names=["p"])
    options = {"threads": 1, "epochs": 100, "hidden": (16,)}
    found = pv.diagnose(ImageModel(generator(), ["p"], (H, W)), data, learn="generative", learn_options=options)
    assert found.learned is not None and found.learned.claimed, found.table()
    chain = found.system(residual="max").stages("image")
    outputs = [s.output for s in chain]
    assert outputs[0] == "image_canonical_render0" and outputs[-3:] == ["image_canonical", "image_generated", "image"], found.table()
    kept = [4, 11, 12, 19]
    closed = pv.ClosedLoop(pv.Discrete({p: p, **{f"y{k}": pv.Expr.var(f"image_{k}") for k in kept}}), chain)
    x0 = np.column_stack([np.linspace(-1.0, 1.0, 21), np.zeros((21, len(kept)))])
    zero = {pid: np.zeros(21) for pid, _, _ in closed.parameters()}  # the residual bounds at 0
    np.testing.assert_allclose(closed.simulate(x0, 1, zero)[:, 1, 1:], found.final_model.predict(x0[:, :1])[:, kept], atol=1e-9)
