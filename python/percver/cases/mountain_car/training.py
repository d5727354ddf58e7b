"""Training the Mountain Car models with torch (paper, Appendix A.2-A.7) and exporting them to ONNX.

Models (hidden sizes from a preset; "paper" is the paper's):

- generator g_c: p -> image, tanh hidden layers, sigmoid output, binary cross-entropy (BCE);
- contrast g_ct and blur g_b: (canonical image, delta) -> image, one tanh layer, sigmoid output,
  BCE plus weight decay, trained on the true canonical images of D;
- estimator h_e: image -> p, tanh layers, tanh output mapped by 0.9 out - 0.3, least squares on all
  images of D plus synthetic composites g_b(g_ct(y_c, delta_c), delta_b) (delta_c in [0.5, 2],
  delta_b in [0, 0.15], the composite row's ranges) made by the trained noise models;
- controller h_c: (p, v) -> u, two sigmoid layers, tanh output. The paper borrows a verified
  controller (Ivanov et al.); a self-contained network set needs its own, so it is fitted (least
  squares) to :func:`pump`, a smooth energy-pumping policy that meets the reward property with a
  margin and tolerates position errors of +-0.05.

Inputs are rescaled to about [-1, 1] during training; the scaling is folded into the first layer on
export, so every ONNX file takes raw inputs (p, pixels, delta, v) like the authors' networks. A
tenth of the positions is held out for the test losses recorded in ``networks.json``.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from percver.cases.mountain_car import dynamics
from percver.cases.mountain_car.camera import PIXELS
from percver.cases.mountain_car.dataset import Dataset
from percver.cases.mountain_car.networks import ESTIMATE_OFFSET, ESTIMATE_SCALE, OUR_FILES, ROLES, training_domain
from percver.errors import InputError, MissingDependencyError, NetworkFormatError
from percver.formats import load_network, save_network
from percver.networks import Layer, Network

try:
    import torch
    from torch import nn
    from torch.nn import functional as F
except ImportError:
    raise MissingDependencyError("training the Mountain Car models needs torch: pip install 'percver[train]'") from None


@dataclass(frozen=True)
class Spec:
    """Size and optimisation of one model: Adam with L2 ``weight_decay``, cosine learning-rate decay."""

    hidden: tuple
    epochs: int
    batch: int = 256
    lr: float = 3e-3
    weight_decay: float = 0.0


PRESETS = {
    "paper": {
        "generator": Spec((50, 100), epochs=1500, batch=128),
        "contrast": Spec((50,), epochs=60, weight_decay=1e-6),
        "blur": Spec((50,), epochs=60, weight_decay=1e-6),
        "estimator": Spec((20, 20, 20), epochs=40, lr=2e-3),
        "controller": Spec((16, 16), epochs=150, batch=1024, lr=1e-2),
    },
    # percver's shipped networks: narrower noise models (smaller files, cheaper to verify); narrower
    # than 32 they lose accuracy at low contrast (delta_c = 0.3). The generator keeps the paper's
    # size: its errors are amplified by the contrast model at low contrast (a [16, 32] generator gave
    # estimate errors up to 0.36 there), and with one input it is cheap to verify anyway.
    "small": {
        "generator": Spec((50, 100), epochs=1500, batch=128),
        "contrast": Spec((32,), epochs=60, weight_decay=1e-6),
        "blur": Spec((32,), epochs=60, weight_decay=1e-6),
        "estimator": Spec((20, 20, 20), epochs=40, lr=2e-3),
        "controller": Spec((16, 16), epochs=150, batch=1024, lr=1e-2),
    },
}
TEST_FRACTION = 0.1
COMPOSITES_PER_POSITION = 50  # the paper's 100,000 composites for 2000 positions
COMPOSITE_CHUNK = 10_000
ROUND_TRIP_TOLERANCE = 1e-5
# Energy-pumping policy of the controller (see pump): gain on v, energy margin and its smoothing.
PUMP_GAIN, PUMP_MARGIN, PUMP_WIDTH = 300.0, 1e-4, 2e-5


def pump(p, v):
    """Push along the velocity (``tanh(300 v)``) until the energy ``v^2/2 + 0.0025/3 sin(3p)`` exceeds
    the goal's potential by 1e-4, then coast (smoothly, over 2e-5 of energy). From p0 in [-0.6, -0.4]
    this reaches the goal with reward at least 92.9 (92.8 with +-0.05 uniform noise on p)."""
    xp = torch if isinstance(p, torch.Tensor) else np
    potential = dynamics.GRAVITY / 3
    energy = 0.5 * v * v + potential * xp.sin(3 * p)
    needed = potential * np.sin(3 * dynamics.GOAL) + PUMP_MARGIN
    gate = 1 / (1 + xp.exp((energy - needed) / PUMP_WIDTH))
    return xp.tanh(PUMP_GAIN * v) * gate


class MLP(nn.Module):
    """Dense layers with input and output affine maps (folded into the exported network)."""

    def __init__(self, n_in, hidden, n_out, activation, output, in_scale, in_offset, out_scale=1.0, out_offset=0.0):
        super().__init__()
        sizes = [n_in, *hidden, n_out]
        self.linears = nn.ModuleList(nn.Linear(a, b) for a, b in zip(sizes, sizes[1:]))
        self.activation, self.output = activation, output
        self.register_buffer("in_scale", torch.as_tensor(np.broadcast_to(in_scale, n_in).copy(), dtype=torch.float32))
        self.register_buffer("in_offset", torch.as_tensor(np.broadcast_to(in_offset, n_in).copy(), dtype=torch.float32))
        self.out_scale, self.out_offset = float(out_scale), float(out_offset)

    def logits(self, x):
        h = x * self.in_scale + self.in_offset
        for linear in self.linears[:-1]:
            h = _ACT[self.activation](linear(h))
        return self.linears[-1](h)

    def forward(self, x):
        return _ACT[self.output](self.logits(x)) * self.out_scale + self.out_offset

    def to_network(self, name: str) -> Network:
        """The same function as a percver Network (float64 copies of the weights)."""
        weights = [(lin.weight.detach().double().numpy(), lin.bias.detach().double().numpy()) for lin in self.linears]
        scale, offset = self.in_scale.double().numpy(), self.in_offset.double().numpy()
        first_w, first_b = weights[0]
        weights[0] = (first_w * scale[None, :], first_b + first_w @ offset)
        acts = [self.activation] * (len(weights) - 1) + [self.output]
        mapped = (self.out_scale, self.out_offset) != (1.0, 0.0)
        return Network(
            [Layer(w, b, a) for (w, b), a in zip(weights, acts)],
            scale=self.out_scale if mapped else None,
            offset=self.out_offset if mapped else None,
            name=name,
        )


_ACT = {"tanh": torch.tanh, "sigmoid": torch.sigmoid}


def _range_map(lo, hi):
    """(scale, offset) taking [lo, hi] to [-1, 1]."""
    return 2.0 / (hi - lo), -(hi + lo) / (hi - lo)


def build(role: str, hidden) -> MLP:
    """An untrained model of ``role`` with raw inputs, as the chain uses it."""
    p_scale, p_offset = _range_map(dynamics.P_MIN, dynamics.P_MAX)
    if role == "generator":
        return MLP(1, hidden, PIXELS, "tanh", "sigmoid", p_scale, p_offset)
    if role in ("contrast", "blur"):
        lo, hi = dynamics.CONTRAST_RANGE if role == "contrast" else dynamics.BLUR_RANGE
        d_scale, d_offset = _range_map(lo, hi)
        return MLP(PIXELS + 1, hidden, PIXELS, "tanh", "sigmoid",
                   np.r_[np.ones(PIXELS), d_scale], np.r_[np.zeros(PIXELS), d_offset])  # fmt: skip
    if role == "estimator":
        return MLP(PIXELS, hidden, 1, "tanh", "tanh", 1.0, 0.0, ESTIMATE_SCALE, ESTIMATE_OFFSET)
    if role == "controller":
        v_scale = 1.0 / dynamics.V_MAX
        return MLP(2, hidden, 1, "sigmoid", "tanh", [p_scale, v_scale], [p_offset, 0.0])
    raise InputError(f"unknown model role '{role}'; roles are {list(ROLES)}")


@dataclass
class Fit:
    """Outcome of training one model."""

    role: str
    spec: Spec
    train_loss: float
    test_loss: float
    test_metric: float
    metric: str
    seconds: float
    model: MLP

    def record(self) -> dict:
        return {
            "file": OUR_FILES[self.role], "hidden": list(self.spec.hidden), **{k: v for k, v in asdict(self.spec).items() if k != "hidden"},
            "train_loss": self.train_loss, "test_loss": self.test_loss, self.metric: self.test_metric, "seconds": round(self.seconds, 2),
        }  # fmt: skip


def _fit(model, loss_fn, x, y, x_test, y_test, spec: Spec, seed: int, desc: str, progress: bool) -> tuple[float, float]:
    """Mini-batch Adam; returns (last epoch's mean training loss, test loss)."""
    generator = torch.Generator().manual_seed(seed)
    optimizer = torch.optim.Adam(model.parameters(), lr=spec.lr, weight_decay=spec.weight_decay)
    steps_per_epoch = max(1, -(-len(x) // spec.batch))
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, spec.epochs * steps_per_epoch, eta_min=spec.lr * 0.01)
    epochs = range(spec.epochs)
    if progress:
        from tqdm import tqdm

        epochs = tqdm(epochs, desc=desc, unit="epoch")
    train_loss = float("nan")
    for _ in epochs:
        order = torch.randperm(len(x), generator=generator)
        total = 0.0
        for start in range(0, len(x), spec.batch):
            batch = order[start : start + spec.batch]
            loss = loss_fn(model, x[batch], y[batch])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            schedule.step()
            total += loss.item() * len(batch)
        train_loss = total / len(x)
        if progress:
            epochs.set_postfix(loss=f"{train_loss:.3g}")
    with torch.no_grad():
        test_loss = float(loss_fn(model, x_test, y_test)) if len(x_test) else float("nan")
    return train_loss, test_loss


def _bce(model, x, y):
    return F.binary_cross_entropy_with_logits(model.logits(x), y)


def _squared(model, x, y):
    return F.mse_loss(model(x)[:, 0], y)


def _tensor(a) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a, dtype=np.float32))


def _image_fit(role, spec, x, y, x_test, y_test, seed, progress) -> Fit:
    model = build(role, spec.hidden)
    start = time.perf_counter()
    x, y, x_test, y_test = map(_tensor, (x, y, x_test, y_test))
    train_loss, test_loss = _fit(model, _bce, x, y, x_test, y_test, spec, seed, role, progress)
    with torch.no_grad():
        mse = float(F.mse_loss(model(x_test), y_test)) if len(x_test) else float("nan")
    return Fit(role, spec, train_loss, test_loss, mse, "test_pixel_mse", time.perf_counter() - start, model)


def _composites(dataset: Dataset, index, contrast: Network, blur: Network, count: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """``count`` images g_b(g_ct(y_c, delta_c), delta_b) (float32) of random positions of ``index``, with their positions."""
    row = dynamics.noise_row("composite")
    which = rng.choice(np.asarray(index), count)
    delta_c = rng.uniform(*row["delta_c"], count)
    delta_b = rng.uniform(*row["delta_b"], count)
    images = np.empty((count, PIXELS), dtype=np.float32)
    for start in range(0, count, COMPOSITE_CHUNK):  # chunks keep the float64 network passes small
        part = slice(start, start + COMPOSITE_CHUNK)
        contrasted = contrast(np.column_stack([dataset.canonical[which[part]].reshape(-1, PIXELS), delta_c[part]]))
        images[part] = blur(np.column_stack([contrasted, delta_b[part]]))
    return images, dataset.positions[which]


def _estimator_fit(spec, dataset, train_idx, test_idx, noise_models, composites, seed, progress) -> Fit:
    rng = np.random.default_rng(seed)
    x, y = dataset.images(train_idx)
    x_test, y_test = dataset.images(test_idx)
    if composites:
        share = max(1, round(composites * len(test_idx) / dataset.n_positions))
        cx, cy = _composites(dataset, train_idx, *noise_models, composites - share, rng)
        tx, ty = _composites(dataset, test_idx, *noise_models, share, rng)
        x, y = np.concatenate([x, cx]), np.concatenate([y, cy])
        x_test, y_test = np.concatenate([x_test, tx]), np.concatenate([y_test, ty])
    model = build("estimator", spec.hidden)
    start = time.perf_counter()
    x, y, x_test, y_test = map(_tensor, (x, y, x_test, y_test))
    train_loss, test_loss = _fit(model, _squared, x, y, x_test, y_test, spec, seed, "estimator", progress)
    with torch.no_grad():
        mae = float((model(x_test)[:, 0] - y_test).abs().mean())
    return Fit("estimator", spec, train_loss, test_loss, mae, "test_position_mae", time.perf_counter() - start, model)


def controller_check(network: Network, noise: float = 0.0, seed: int = 0, n: int = 81) -> dict:
    """Closed loop on the true state (plus uniform noise of +-``noise`` on p) from p0 over [-0.6, -0.4]."""
    rng = np.random.default_rng(seed)
    p0 = np.linspace(*dynamics.ROWS["canonical"]["p0"], n)
    runs = dynamics.simulate(p0, lambda k, p, v, active: network(np.column_stack([p + rng.uniform(-noise, noise, len(p)), v]))[:, 0])
    return {"noise": noise, "safe_fraction": float(runs.safe.mean()), "min_reward": float(runs.reward.min()),
            "max_steps": int(runs.reached_at.max())}  # fmt: skip


def _controller_fit(spec, seed, progress) -> Fit:
    """Least squares to :func:`pump` on states of the whole box and of noisy closed-loop runs of the policy."""
    rng = np.random.default_rng(seed)
    box = np.column_stack([rng.uniform(dynamics.P_MIN, dynamics.P_MAX, 20000), rng.uniform(-dynamics.V_MAX, dynamics.V_MAX, 20000)])
    runs = dynamics.simulate(rng.uniform(-0.65, -0.35, 400), lambda k, p, v, a: pump(p + rng.uniform(-0.05, 0.05, len(p)), v))
    visited = np.column_stack([runs.p[:, :-1][runs.active], runs.v[:, :-1][runs.active]])
    states = np.concatenate([box, visited])
    targets = pump(states[:, 0], states[:, 1])
    test = rng.random(len(states)) < TEST_FRACTION
    model = build("controller", spec.hidden)
    start = time.perf_counter()
    x, y, x_test, y_test = map(_tensor, (states[~test], targets[~test], states[test], targets[test]))
    train_loss, test_loss = _fit(model, _squared, x, y, x_test, y_test, spec, seed, "controller", progress)
    check = controller_check(model.to_network("controller"), noise=0.05, seed=seed)
    return Fit("controller", spec, train_loss, test_loss, check["min_reward"], "min_reward_noise_0.05",
               time.perf_counter() - start, model)  # fmt: skip


def _single_precision(path) -> None:
    """Store an ONNX graph's constants and values as float32: torch trained in float32, and the files
    (shipped with percver) are half the size of percver's float64 ones."""
    import onnx
    from onnx import TensorProto, numpy_helper

    model = onnx.load(str(path))
    for tensor in model.graph.initializer:
        tensor.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(tensor).astype(np.float32), tensor.name))
    for value in (*model.graph.input, *model.graph.output):
        value.type.tensor_type.elem_type = TensorProto.FLOAT
    onnx.checker.check_model(model)
    onnx.save(model, str(path))


def export(model: MLP, role: str, path) -> Network:
    """Write ``model`` as float32 ONNX, with its training domain, and check that percver reads back the same function (to 1e-5)."""
    network = model.to_network(role).with_domain(training_domain(role))
    save_network(network, path)
    _single_precision(path)
    loaded = load_network(path)
    n_in = network.n_in
    probe = np.random.default_rng(0).uniform(0.0, 1.0, (64, n_in))
    if role == "generator":
        probe[:, 0] = np.linspace(dynamics.P_MIN, dynamics.P_MAX, 64)
    elif role == "controller":
        probe = np.column_stack([np.linspace(dynamics.P_MIN, dynamics.P_MAX, 64), np.linspace(-dynamics.V_MAX, dynamics.V_MAX, 64)])
    with torch.no_grad():
        expected = model(_tensor(probe)).double().numpy()
    error = float(np.max(np.abs(loaded(probe) - expected)))
    if not error <= ROUND_TRIP_TOLERANCE:
        raise NetworkFormatError(f"{path}: the exported {role} differs from the torch model by {error:.2e} (> {ROUND_TRIP_TOLERANCE})")
    return loaded


@dataclass
class Training:
    """What :func:`train` did: one :class:`Fit` per model and the ``networks.json`` record."""

    fits: dict
    record: dict
    out: Path

    def summary(self) -> str:
        lines = [f"{'model':<11} {'hidden':<12} {'train loss':>11} {'test loss':>11}  {'test metric':<32} {'seconds':>8}"]
        for fit in self.fits.values():
            lines.append(
                f"{fit.role:<11} {str(list(fit.spec.hidden)):<12} {fit.train_loss:>11.4g} {fit.test_loss:>11.4g}  "
                f"{fit.metric + ' ' + format(fit.test_metric, '.4g'):<32} {fit.seconds:>8.1f}"
            )
        return "\n".join(lines)


def train(
    dataset,
    out,
    *,
    preset: str = "paper",
    models=ROLES,
    seed: int = 0,
    epochs_scale: float = 1.0,
    overrides: dict | None = None,
    composites: int | None = None,
    threads: int = 1,
    progress: bool = True,
    command: str | None = None,
) -> Training:
    """Train ``models`` (any of generator, contrast, blur, estimator, controller) on ``dataset`` (a
    :class:`Dataset` or an ``.npz`` path) and write ``ROLE.onnx`` plus ``networks.json`` to ``out``.

    ``epochs_scale`` multiplies every preset's epochs (reduced runs); ``overrides`` replaces fields of
    the preset's :class:`Spec` per model, e.g. ``{"generator": {"batch": 16}}``; ``composites`` is the number of
    synthetic composites for the estimator (default 50 per position, the paper's 100,000 for D).
    The estimator's composites come from ``contrast.onnx`` and ``blur.onnx`` in ``out``, trained in
    the same run or earlier. ``threads`` sets torch's threads: the models are small, and more threads
    mostly add synchronisation (on a busy 2-core machine, 2 threads ran 10-30x slower than 1).
    ``command`` is recorded (the CLI passes its command line).
    """
    if preset not in PRESETS:
        raise InputError(f"unknown preset '{preset}'; choose one of {list(PRESETS)}")
    unknown = sorted(set(models) - set(ROLES))
    if unknown:
        raise InputError(f"unknown model(s) {unknown}; choose among {list(ROLES)}")
    if not epochs_scale > 0:
        raise InputError(f"epochs_scale must be positive, got {epochs_scale}")
    torch.set_num_threads(int(threads))
    dataset = dataset if isinstance(dataset, Dataset) else Dataset.load(dataset)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    specs = {role: replace(spec, epochs=max(1, round(spec.epochs * epochs_scale))) for role, spec in PRESETS[preset].items()}
    for role, fields in (overrides or {}).items():
        if role not in specs or not set(fields) <= set(Spec.__dataclass_fields__):
            raise InputError(f"overrides: '{role}': {sorted(fields)} is not a model and fields of {list(Spec.__dataclass_fields__)}")
        specs[role] = replace(specs[role], **{k: tuple(v) if k == "hidden" else v for k, v in fields.items()})
    rng = np.random.default_rng(seed)
    order = rng.permutation(dataset.n_positions)
    n_test = max(1, round(TEST_FRACTION * dataset.n_positions))
    test_idx, train_idx = np.sort(order[:n_test]), np.sort(order[n_test:])
    if composites is None:
        composites = COMPOSITES_PER_POSITION * dataset.n_positions
    started = time.perf_counter()
    fits = {}
    for i, role in enumerate(r for r in ROLES if r in models):
        torch.manual_seed(seed + i)
        spec = specs[role]
        if role == "generator":
            canonical = dataset.canonical.reshape(-1, PIXELS)
            p = dataset.positions[:, None]
            fit = _image_fit(role, spec, p[train_idx], canonical[train_idx], p[test_idx], canonical[test_idx], seed, progress)
        elif role in ("contrast", "blur"):
            clean, delta, noised = dataset.noise_pairs(role, train_idx)
            clean_t, delta_t, noised_t = dataset.noise_pairs(role, test_idx)
            fit = _image_fit(role, spec, np.column_stack([clean, delta]), noised,
                             np.column_stack([clean_t, delta_t]), noised_t, seed, progress)  # fmt: skip
        elif role == "estimator":
            noise_models = tuple(_load_trained(out, name) for name in ("contrast", "blur")) if composites else ()
            fit = _estimator_fit(spec, dataset, train_idx, test_idx, noise_models, composites, seed, progress)
        else:
            fit = _controller_fit(spec, seed, progress)
        export(fit.model, role, out / OUR_FILES[role])
        fits[role] = fit
    record = _record(out, fits, dataset, preset, seed, epochs_scale, composites, command, time.perf_counter() - started)
    return Training(fits, record, out)


def _load_trained(out: Path, role: str) -> Network:
    path = out / OUR_FILES[role]
    if not path.is_file():
        raise InputError(
            f"the estimator's composites need the {role} model, but {path} does not exist; train "
            f"{role} first (or in the same run), or pass composites=0"
        )
    return load_network(path)


def _record(out, fits, dataset, preset, seed, epochs_scale, composites, command, seconds) -> dict:
    """Merge this run into ``out/networks.json`` (models trained earlier keep their entries)."""
    import percver

    path = out / "networks.json"
    record = json.loads(path.read_text()) if path.is_file() else {"models": {}}
    run = {
        "command": command or (
            f"percver.cases.mountain_car.train({dataset.meta.get('path', 'dataset')!r}, {str(out)!r}, preset={preset!r}, "
            f"models={list(fits)}, seed={seed}, epochs_scale={epochs_scale}, composites={composites})"
        ),
        "seed": seed, "preset": preset, "epochs_scale": epochs_scale, "composites": composites,
        "dataset": {key: value for key, value in dataset.meta.items()}, "percver": percver.__version__,
        "torch": torch.__version__, "threads": torch.get_num_threads(), "seconds": round(seconds, 1),
    }  # fmt: skip
    for role, fit in fits.items():
        record["models"][role] = {**fit.record(), "run": len(record.get("runs", []))}
    record["runs"] = [*record.get("runs", []), run]
    if "controller" in fits:
        record["models"]["controller"]["checks"] = [
            controller_check(load_network(out / OUR_FILES["controller"]), noise) for noise in (0.0, 0.05)
        ]
    path.write_text(json.dumps(record, indent=2) + "\n")
    return record
