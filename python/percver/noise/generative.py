"""Generative models of benign noise: (canonical measurement, conditions) -> measurement.

The paper's contrast and blur models (Appendix A) map a canonical image and the noise parameter
to the noisy image through a tanh layer and sigmoid outputs, trained with binary cross-entropy.
The conditions may be noise parameters, state features or a latent; for measurements outside
[0, 1] the outputs are linear, trained by least squares on standardised targets and mapped back
by the network's output scale and offset.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from percver.errors import InputError
from percver.noise import training

LOSSES = ("bce", "mse")


class GenerativeModel:
    """A ``network`` taking the canonical measurement (m values), then the conditions, to m values."""

    def __init__(self, network, n_conditions: int, name: str | None = None):
        if network.n_in != network.n_out + n_conditions:
            raise InputError(
                f"a generative model takes the canonical measurement ({network.n_out} values) and "
                f"{n_conditions} conditions; '{network.name}' has {network.n_in} inputs"
            )
        self.network = network
        self.n_conditions = int(n_conditions)
        self.name = name or network.name

    def __call__(self, canonical, conditions) -> np.ndarray:
        return self.network(np.column_stack([canonical, np.asarray(conditions).reshape(len(canonical), -1)]))

    def save(self, path) -> None:
        """The network as ONNX; the number of conditions is its inputs minus its outputs."""
        from percver.formats import save_network

        save_network(self.network, path)

    @classmethod
    def load(cls, path) -> "GenerativeModel":
        from percver.formats import load_network

        network = load_network(path)
        return cls(network, network.n_in - network.n_out, Path(path).stem)

    def __repr__(self) -> str:
        return f"GenerativeModel({self.name!r}, {self.network!r})"


def train_generative(
    canonical,
    conditions,
    measured,
    hidden=(64,),
    *,
    loss: str | None = None,
    epochs: int = 300,
    batch: int = 32,
    lr: float = 3e-3,
    weight_decay: float = 0.0,
    seed: int = 0,
    threads: int | None = None,
    progress: bool = False,
    name: str = "generative",
) -> GenerativeModel:
    """Train g on (``canonical`` N x m, ``conditions`` N x c) -> ``measured`` N x m.

    ``loss`` "bce" (sigmoid outputs; the default when every measured value lies in [0, 1]) or
    "mse" (linear outputs on standardised targets)."""
    torch = training.require_torch()
    canonical, measured = np.asarray(canonical, dtype=float), np.asarray(measured, dtype=float)
    conditions = np.asarray(conditions, dtype=float).reshape(len(canonical), -1)
    if canonical.ndim != 2 or canonical.shape != measured.shape:
        raise InputError(
            f"generative training needs canonical and measured values of one shape N x m, got {canonical.shape} and {measured.shape}"
        )
    bounded = bool(np.all((measured >= 0) & (measured <= 1)))
    loss = loss or ("bce" if bounded else "mse")
    if loss not in LOSSES:
        raise InputError(f"unknown loss '{loss}'; use one of {LOSSES}")
    if loss == "bce" and not bounded:
        raise InputError("the 'bce' loss needs measurements in [0, 1]; use loss='mse'")
    training.session(torch, seed, threads)
    inputs = np.column_stack([canonical, conditions])
    module = training.mlp(torch, (inputs.shape[1], *hidden, measured.shape[1]), torch.nn.Tanh)
    if loss == "bce":
        targets, scale, offset = measured, None, None
        loss_fn = torch.nn.BCEWithLogitsLoss()
    else:
        offset, scale = measured.mean(axis=0), np.maximum(measured.std(axis=0), 1e-9)
        targets = (measured - offset) / scale
        loss_fn = torch.nn.MSELoss()
    training.fit(
        torch,
        module,
        inputs,
        targets,
        loss_fn,
        epochs=epochs,
        batch=batch,
        lr=lr,
        weight_decay=weight_decay,
        seed=seed,
        progress=progress,
        desc=name,
    )
    if loss == "bce":
        module.append(torch.nn.Sigmoid())
    return GenerativeModel(training.to_network(module, name, scale=scale, offset=offset, inputs=inputs), conditions.shape[1], name)
