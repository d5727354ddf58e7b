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

from pathlib import Path

import numpy as np

from percver.cases.f1tenth import world
from percver.errors import InputError, MissingFileError
from percver.noise import denoiser as generic_denoiser
from percver.noise import thresholds as generic
from percver.noise.knockout import POSITIVE_WEIGHT, KnockoutModel, train_knockout

# Public names of this module since before percver.noise held them generically.
from percver.noise.thresholds import fit_thresholds, label  # noqa: F401

# Knocked-out rays read the range limit: 5 m, normalised (5 - 2.5) / 5.
KNOCKED = 0.5
DENOISER_SCALE = 0.5
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
    return generic.noised(real, canonical, threshold, limit)


class ThresholdCurve(generic.ThresholdCurve):
    """Mean absolute error (m per ray) between noised canonical and real scans for each
    candidate t_Delta, and the minimiser ``best`` (t_Delta*)."""

    def summary(self) -> dict:
        k = int(np.argmin(self.errors))
        pick = np.unique(
            np.clip(np.searchsorted(self.thresholds, [0.02, 0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 4.0]), 0, len(self.thresholds) - 1)
        )
        return {
            "t_delta": self.best,
            "error_at_best_m": float(self.errors[k]),
            "knocked_share_at_best": float(self.knocked_share[k]),
            "error_without_noise_model_m": float(self.errors[-1]),
            "curve": [
                {"t": float(self.thresholds[i]), "error_m": float(self.errors[i]), "knocked_share": float(self.knocked_share[i])}
                for i in pick
            ],
        }


def threshold_curve(real, canonical, thresholds=None) -> ThresholdCurve:
    """The error of the noised canonical scans against ``real`` (both N x 21, metres) per t_Delta.

    The last candidate is beyond every difference, i.e. the canonical model without noise."""
    if thresholds is None:
        thresholds = np.concatenate([np.geomspace(0.01, 4.0, 80), [world.CONTROLLER_RANGE + 1]])
    thresholds = np.asarray(thresholds, dtype=float)
    errors, share = generic.threshold_errors(real, canonical, thresholds, world.CONTROLLER_RANGE, metric="mae")
    return ThresholdCurve(thresholds, errors, share)


# ------------------------------------------------------------------------------------------ models
def _network(path):
    from percver.formats import load_network

    return load_network(path)


class NoiseModel(KnockoutModel):
    """A knock-out classifier ``network`` (24 -> 21 probabilities) with per-ray ``thresholds``;
    knocked-out rays read the normalised range limit."""

    def __init__(self, network, thresholds, name: str | None = None):
        if network.n_in != 24 or network.n_out != 21:
            raise InputError(
                f"a knock-out classifier maps 24 inputs (21 rays, 3 pose features) to 21 probabilities; "
                f"'{network.name}' maps {network.n_in} -> {network.n_out}"
            )
        super().__init__(network, thresholds, KNOCKED, name)

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
        from percver.formats import save_network

        save_network(self.network, network_path)
        np.save(thresholds_path, self.thresholds)


class Denoiser(generic_denoiser.Denoiser):
    """h_d of the F1/10 car: 21 normalised real rays -> 21 normalised canonical rays."""

    def __init__(self, network, name: str | None = None):
        if network.n_in != 21 or network.n_out != 21:
            raise InputError(f"a denoiser maps 21 rays to 21 rays; '{network.name}' maps {network.n_in} -> {network.n_out}")
        super().__init__(network, DENOISER_SCALE, name)

    @classmethod
    def load(cls, path) -> "Denoiser":
        return cls(_network(path), Path(path).stem)


# ------------------------------------------------------------------------------------------ training
def train_classifier(
    inputs,
    labels,
    hidden=SIZES["5x100"],
    *,
    epochs: int = 60,
    batch: int = 256,
    lr: float = 2e-3,
    positive_weight: float = POSITIVE_WEIGHT,
    seed: int = 0,
    threads: int | None = None,
    progress: bool = False,
    name: str | None = None,
) -> NoiseModel:
    """Train c_n on ``inputs`` (N x 24) and ``labels`` (N x 21); thresholds fitted on the same data."""
    inputs, labels = np.asarray(inputs, dtype=float), np.asarray(labels, dtype=float)
    if inputs.ndim != 2 or inputs.shape[1] != 24 or labels.shape != (len(inputs), 21):
        raise InputError(f"classifier training needs inputs N x 24 and labels N x 21, got {inputs.shape} and {labels.shape}")
    size = f"{len(hidden)}x{hidden[0]}" if len(set(hidden)) == 1 else "x".join(map(str, hidden))
    model = train_knockout(
        inputs,
        labels,
        hidden,
        knocked=KNOCKED,
        epochs=epochs,
        batch=batch,
        lr=lr,
        positive_weight=positive_weight,
        seed=seed,
        threads=threads,
        progress=progress,
        name=name or f"noiser{size}",
    )
    return NoiseModel(model.network, model.thresholds, model.name)


def train_denoiser(real_normalised, canonical_normalised, **training) -> Denoiser:
    """Train h_d on pairs (real, canonical) of normalised 21-ray scans; ``training`` as
    :func:`percver.noise.train_denoiser` takes it (hidden, epochs, batch, lr, seed, ...)."""
    model = generic_denoiser.train_denoiser(real_normalised, canonical_normalised, scale=DENOISER_SCALE, **training)
    return Denoiser(model.network)
