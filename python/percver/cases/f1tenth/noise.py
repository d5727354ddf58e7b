"""The paper's adversarial LiDAR noise model (section 4.2, Appendix B.5) and denoiser (B.6).

Labels: a ray of a real scan is adversarial (n = 1) when it differs from the canonical scan
at the estimated pose by more than t_Delta; t_Delta* minimises the error between noised
canonical scans (labelled rays set to the range limit) and the real scans.

Classifier c_n: 24 inputs (the 21 normalised canonical rays, then the pose features of
``world.pose_features``) -> tanh hidden layers -> 21 sigmoid knock-out probabilities,
trained with BCE weighting class 1 four times; per-ray thresholds turn probabilities into
knock-outs, and a knocked-out ray reads the range limit (0.5 normalised).

Denoiser h_d: 21 normalised real rays -> 100 tanh -> 21 tanh, times 0.5 -> the normalised
canonical scan; BCE on the [0, 1]-shifted scans, with weight decay.

The authors' files (``noiser5x100.yml`` + ``thresholds5x100.npy``, ``denoiser.yml``) and the
ones trained here (ONNX + ``.npy``) load into the same ``NoiseModel`` and ``Denoiser``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from percver.cases.f1tenth import world
from percver.errors import InputError, MissingDependencyError, MissingFileError

# Knocked-out rays read the range limit: 5 m, normalised (5 - 2.5) / 5.
KNOCKED = 0.5
DENOISER_SCALE = 0.5
POSITIVE_WEIGHT = 4.0
SIZES = {
    "3x100": (100,) * 3,
    "4x100": (100,) * 4,
    "5x100": (100,) * 5,
    "6x100": (100,) * 6,
    "6x200": (200,) * 6,
}


# ------------------------------------------------------------------------------------------ labels
def noised(real, canonical, threshold, limit: float = world.CONTROLLER_RANGE) -> np.ndarray:
    """The canonical scans with the rays labelled at ``threshold`` set to the range limit."""
    return np.where(np.abs(real - canonical) > threshold, limit, canonical)


def label(real, canonical, threshold) -> np.ndarray:
    """n_i^d = 1 where |real - canonical| > t_Delta (N x 21 booleans)."""
    return np.abs(np.asarray(real) - np.asarray(canonical)) > threshold


@dataclass(frozen=True)
class ThresholdCurve:
    """Mean absolute error (m per ray) between noised canonical and real scans for each
    candidate t_Delta, and the minimiser ``best`` (t_Delta*)."""

    thresholds: np.ndarray
    errors: np.ndarray
    knocked_share: np.ndarray

    @property
    def best(self) -> float:
        return float(self.thresholds[int(np.argmin(self.errors))])

    def summary(self) -> dict:
        k = int(np.argmin(self.errors))
        pick = np.unique(np.clip(np.searchsorted(self.thresholds, [0.02, 0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0]), 0, len(self.thresholds) - 1))
        return {
            "t_delta": self.best,
            "error_at_best_m": float(self.errors[k]),
            "knocked_share_at_best": float(self.knocked_share[k]),
            "error_without_noise_model_m": float(self.errors[-1]),
            "curve": [{"t": float(self.thresholds[i]), "error_m": float(self.errors[i]),
                       "knocked_share": float(self.knocked_share[i])} for i in pick],
        }


def threshold_curve(real, canonical, thresholds=None) -> ThresholdCurve:
    """The error of the noised canonical scans against ``real`` (both N x 21, metres) per t_Delta.

    The last candidate is beyond every difference, i.e. the canonical model without noise."""
    real, canonical = np.asarray(real, dtype=float), np.asarray(canonical, dtype=float)
    if real.shape != canonical.shape:
        raise InputError(f"real scans {real.shape} and canonical scans {canonical.shape} must have the same shape")
    if thresholds is None:
        thresholds = np.concatenate([np.geomspace(0.01, 4.0, 80), [world.CONTROLLER_RANGE + 1]])
    thresholds = np.asarray(thresholds, dtype=float)
    difference = np.abs(real - canonical)
    errors = np.empty(len(thresholds))
    share = np.empty(len(thresholds))
    for i, t in enumerate(thresholds):
        knocked = difference > t
        errors[i] = np.abs(np.where(knocked, world.CONTROLLER_RANGE, canonical) - real).mean()
        share[i] = knocked.mean()
    return ThresholdCurve(thresholds, errors, share)


# ------------------------------------------------------------------------------------------ models
def _network(path):
    from percver.networks import load_network

    return load_network(path)


class NoiseModel:
    """A knock-out classifier ``network`` (24 -> 21 probabilities) with per-ray ``thresholds``."""

    def __init__(self, network, thresholds, name: str | None = None):
        thresholds = np.asarray(thresholds, dtype=float).reshape(-1)
        if network.n_in != 24 or network.n_out != 21:
            raise InputError(
                f"a knock-out classifier maps 24 inputs (21 rays, 3 pose features) to 21 probabilities; "
                f"'{network.name}' maps {network.n_in} -> {network.n_out}"
            )
        if thresholds.shape != (21,):
            raise InputError(f"need one threshold per ray (21), got {thresholds.shape[0]}")
        self.network = network
        self.thresholds = thresholds
        self.name = name or network.name

    @classmethod
    def load(cls, network_path, thresholds_path) -> "NoiseModel":
        """From a network file (Verisig ``.yml`` or ``.onnx``) and a ``.npy`` of 21 thresholds."""
        thresholds_path = Path(thresholds_path)
        if not thresholds_path.is_file():
            raise MissingFileError(f"thresholds file not found: {thresholds_path}")
        try:
            thresholds = np.load(thresholds_path)
        except ValueError as error:
            raise InputError(f"'{thresholds_path}' is not a .npy array of 21 thresholds: {error}") from None
        return cls(_network(network_path), thresholds, Path(network_path).stem)

    def save(self, network_path, thresholds_path) -> None:
        self.network.to_onnx(network_path)
        np.save(thresholds_path, self.thresholds)

    def probabilities(self, canonical_normalised, features) -> np.ndarray:
        return self.network(np.column_stack([canonical_normalised, features]))

    def knockouts(self, canonical_normalised, features) -> np.ndarray:
        return self.probabilities(canonical_normalised, features) > self.thresholds

    def apply(self, canonical_normalised, features) -> np.ndarray:
        """g_n: the normalised canonical scans with knocked-out rays at the range limit."""
        return np.where(self.knockouts(canonical_normalised, features), KNOCKED, canonical_normalised)

    def __repr__(self) -> str:
        return f"NoiseModel({self.name!r}, {self.network!r})"


class Denoiser:
    """h_d: normalised real scans -> normalised canonical scans (``DENOISER_SCALE`` x network)."""

    def __init__(self, network, name: str | None = None):
        if network.n_in != 21 or network.n_out != 21:
            raise InputError(f"a denoiser maps 21 rays to 21 rays; '{network.name}' maps {network.n_in} -> {network.n_out}")
        self.network = network
        self.name = name or network.name

    @classmethod
    def load(cls, path) -> "Denoiser":
        return cls(_network(path), Path(path).stem)

    def save(self, path) -> None:
        self.network.to_onnx(path)

    def __call__(self, normalised) -> np.ndarray:
        return DENOISER_SCALE * self.network(normalised)

    def __repr__(self) -> str:
        return f"Denoiser({self.name!r}, {self.network!r})"


def fit_thresholds(probabilities, labels, grid=None) -> np.ndarray:
    """Per ray, the threshold of ``grid`` (default 100 points in [0, 1], as the authors') with
    the highest accuracy on (probabilities, labels)."""
    grid = np.linspace(0.0, 1.0, 100) if grid is None else np.asarray(grid, dtype=float)
    probabilities, labels = np.asarray(probabilities), np.asarray(labels, dtype=bool)
    accuracy = np.stack([((probabilities > t) == labels).mean(axis=0) for t in grid])
    return grid[np.argmax(accuracy, axis=0)]


# ------------------------------------------------------------------------------------------ training
def _torch():
    try:
        import torch
    except ImportError:
        raise MissingDependencyError("training noise models needs torch: pip install 'percver[train]'") from None
    return torch


def _mlp(torch, sizes, hidden_activation, output_activation):
    layers = []
    for k, (n_in, n_out) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(torch.nn.Linear(n_in, n_out))
        last = k == len(sizes) - 2
        if not last or output_activation is not None:
            layers.append((output_activation if last else hidden_activation)())
    return torch.nn.Sequential(*layers)


def to_network(module, name: str):
    """A torch ``Sequential`` of Linear / Tanh / Sigmoid layers as a ``percver.Network``."""
    from percver.networks import Layer, Network

    torch = _torch()
    names = {torch.nn.Tanh: "tanh", torch.nn.Sigmoid: "sigmoid", torch.nn.ReLU: "relu"}
    layers, pending = [], None
    for part in module:
        if isinstance(part, torch.nn.Linear):
            if pending is not None:
                layers.append(Layer(*pending, "identity"))
            pending = (part.weight.detach().double().numpy(), part.bias.detach().double().numpy())
        elif type(part) in names and pending is not None:
            layers.append(Layer(*pending, names[type(part)]))
            pending = None
        else:
            raise InputError(f"cannot convert {type(part).__name__} to a dense layer: use Linear, Tanh, Sigmoid, ReLU")
    if pending is not None:
        layers.append(Layer(*pending, "identity"))
    return Network(layers, name=name)


def _fit(torch, module, inputs, targets, loss_fn, *, epochs, batch, lr, weight_decay, seed, progress, desc):
    """Adam with a cosine schedule on standardised inputs; the standardisation is folded into
    the first layer afterwards, so the module takes the raw inputs (the pose features span a
    few hundredths, too little for a step in them to be learnt unscaled)."""
    inputs = np.asarray(inputs, dtype=np.float64)
    mean, scale = inputs.mean(axis=0), np.maximum(inputs.std(axis=0), 1e-3)
    generator = torch.Generator().manual_seed(seed)
    x = torch.as_tensor(((inputs - mean) / scale).astype(np.float32))
    y = torch.as_tensor(np.asarray(targets, dtype=np.float32))
    optimiser = torch.optim.Adam(module.parameters(), lr=lr, weight_decay=weight_decay)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, max(epochs, 1))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=epochs, desc=desc, unit="epoch")
    for _ in range(epochs):
        order = torch.randperm(len(x), generator=generator)
        total = 0.0
        for lo in range(0, len(x), batch):
            index = order[lo : lo + batch]
            optimiser.zero_grad()
            loss = loss_fn(module(x[index]), y[index])
            loss.backward()
            optimiser.step()
            total += loss.item() * len(index)
        schedule.step()
        if bar is not None:
            bar.set_postfix(loss=f"{total / len(x):.4f}")
            bar.update(1)
    if bar is not None:
        bar.close()
    module.double()  # exported in float64: fold without rounding to float32 again
    first = module[0]
    with torch.no_grad():
        weight = first.weight / torch.as_tensor(scale)
        first.bias.copy_(first.bias - weight @ torch.as_tensor(mean))
        first.weight.copy_(weight)


def train_classifier(inputs, labels, hidden=SIZES["5x100"], *, epochs: int = 60, batch: int = 256, lr: float = 2e-3,
                     positive_weight: float = POSITIVE_WEIGHT, seed: int = 0, threads: int | None = None,
                     progress: bool = False, name: str | None = None) -> NoiseModel:
    """Train c_n on ``inputs`` (N x 24) and ``labels`` (N x 21); thresholds fitted on the same data."""
    torch = _torch()
    if threads:
        torch.set_num_threads(threads)
    inputs, labels = np.asarray(inputs, dtype=float), np.asarray(labels, dtype=float)
    if inputs.ndim != 2 or inputs.shape[1] != 24 or labels.shape != (len(inputs), 21):
        raise InputError(f"classifier training needs inputs N x 24 and labels N x 21, got {inputs.shape} and {labels.shape}")
    torch.manual_seed(seed)
    module = _mlp(torch, (24, *hidden, 21), torch.nn.Tanh, None)
    weight = torch.tensor(positive_weight)
    loss = torch.nn.BCEWithLogitsLoss(pos_weight=weight)  # sigmoid folded into the loss for stability
    size = f"{len(hidden)}x{hidden[0]}" if len(set(hidden)) == 1 else "x".join(map(str, hidden))
    _fit(torch, module, inputs, labels, loss, epochs=epochs, batch=batch, lr=lr, weight_decay=0.0, seed=seed,
         progress=progress, desc=f"noiser {size}")
    module.append(torch.nn.Sigmoid())
    network = to_network(module, name or f"noiser{size}")
    return NoiseModel(network, fit_thresholds(network(inputs), labels > 0.5), network.name)


def train_denoiser(real_normalised, canonical_normalised, *, hidden: int = 100, epochs: int = 60, batch: int = 256,
                   lr: float = 2e-3, weight_decay: float = 1e-5, seed: int = 0, threads: int | None = None,
                   progress: bool = False) -> Denoiser:
    """Train h_d on pairs (real, canonical) of normalised 21-ray scans."""
    torch = _torch()
    if threads:
        torch.set_num_threads(threads)
    torch.manual_seed(seed)
    module = _mlp(torch, (21, hidden, 21), torch.nn.Tanh, torch.nn.Tanh)
    bce = torch.nn.BCELoss()

    def loss(output, target):
        # tanh output times 0.5 is the normalised scan in [-0.5, 0.5]; shifted to [0, 1] for BCE.
        return bce((DENOISER_SCALE * output + 0.5).clamp(1e-7, 1 - 1e-7), target + 0.5)

    target = np.clip(np.asarray(canonical_normalised, dtype=float), -0.5, 0.5)
    _fit(torch, module, real_normalised, target, loss, epochs=epochs, batch=batch, lr=lr, weight_decay=weight_decay,
         seed=seed, progress=progress, desc="denoiser")
    return Denoiser(to_network(module, f"denoiser1x{hidden}"))
