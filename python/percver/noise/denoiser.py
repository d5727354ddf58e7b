"""Denoisers h_d (paper, section 4.2, Appendix B.6): measured -> canonical measurements.

A denoiser is a network from a real measurement vector to its canonical counterpart, its tanh
output scaled by ``scale`` (the normalised measurement range's half-width), trained with BCE on
the [0, 1]-shifted targets. In the closed loop it is one more network stage before the estimator
or controller, so its error is inside the proof.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from percver.errors import InputError
from percver.noise import training


class Denoiser:
    """h_d: normalised measurements -> normalised canonical measurements (``scale`` x network)."""

    def __init__(self, network, scale: float = 0.5, name: str | None = None):
        if network.n_in != network.n_out:
            raise InputError(
                f"a denoiser maps a measurement to one of the same size; '{network.name}' maps {network.n_in} -> {network.n_out}"
            )
        self.network = network
        self.scale = float(scale)
        self.name = name or network.name

    @classmethod
    def load(cls, path, scale: float = 0.5) -> "Denoiser":
        from percver.formats import load_network

        return cls(load_network(path), scale, Path(path).stem)

    def save(self, path) -> None:
        from percver.formats import save_network

        save_network(self.network, path)

    def __call__(self, normalised) -> np.ndarray:
        return self.scale * self.network(normalised)

    def __repr__(self) -> str:
        return f"Denoiser({self.name!r}, {self.network!r})"


def train_denoiser(
    real,
    canonical,
    *,
    scale: float = 0.5,
    hidden: int = 100,
    epochs: int = 60,
    batch: int = 256,
    lr: float = 2e-3,
    weight_decay: float = 1e-5,
    seed: int = 0,
    threads: int | None = None,
    progress: bool = False,
) -> Denoiser:
    """Train h_d on pairs (real, canonical) of normalised measurements in [-scale, scale]
    (N x n each): n -> ``hidden`` tanh -> n tanh, times ``scale``."""
    real, canonical = np.asarray(real, dtype=float), np.asarray(canonical, dtype=float)
    if real.ndim != 2 or real.shape != canonical.shape:
        raise InputError(f"denoiser training needs real and canonical arrays of one shape N x n, got {real.shape} and {canonical.shape}")
    torch = training.require_torch()
    training.session(torch, seed, threads)
    n = real.shape[1]
    module = training.mlp(torch, (n, hidden, n), torch.nn.Tanh, torch.nn.Tanh)
    bce = torch.nn.BCELoss()

    def loss(output, target):
        # The scaled tanh output is the normalised measurement in [-scale, scale]; shifted to [0, 1] for BCE.
        return bce(((scale * output + scale) / (2 * scale)).clamp(1e-7, 1 - 1e-7), (target + scale) / (2 * scale))

    target = np.clip(canonical, -scale, scale)
    training.fit(
        torch,
        module,
        real,
        target,
        loss,
        epochs=epochs,
        batch=batch,
        lr=lr,
        weight_decay=weight_decay,
        seed=seed,
        progress=progress,
        desc="denoiser",
    )
    return Denoiser(training.to_network(module, f"denoiser1x{hidden}"), scale)
