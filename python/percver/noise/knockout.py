"""Knock-out classifiers: the paper's model of adversarial noise (section 4.2).

c_n maps (canonical measurement, state features) to one knock-out probability per output
through tanh hidden layers and sigmoid outputs; per-output thresholds turn probabilities into
knock-outs, and a knocked-out entry reads its ``knocked`` value (a LiDAR ray without echo reads
the range limit). Trained with binary cross-entropy that weights the rare class 1 more.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from percver.errors import InputError, MissingFileError
from percver.noise import training
from percver.noise.thresholds import fit_thresholds

POSITIVE_WEIGHT = 4.0


class KnockoutModel:
    """A classifier ``network`` ((canonical, features) -> probabilities), per-output ``thresholds``
    and the ``knocked`` values (a number or one per output) that knocked-out entries read."""

    def __init__(self, network, thresholds, knocked, name: str | None = None):
        thresholds = np.asarray(thresholds, dtype=float).reshape(-1)
        if thresholds.shape != (network.n_out,):
            raise InputError(f"need one threshold per output of '{network.name}' ({network.n_out}), got {thresholds.shape[0]}")
        if network.n_in < network.n_out:
            raise InputError(
                f"a knock-out classifier takes the canonical measurement ({network.n_out} values) and state "
                f"features; '{network.name}' has only {network.n_in} inputs"
            )
        knocked = np.broadcast_to(np.asarray(knocked, dtype=float), (network.n_out,)).copy()
        if not np.all(np.isfinite(knocked)):
            raise InputError(f"knocked values must be finite, got {knocked}")
        self.network = network
        self.thresholds = thresholds
        self.knocked = knocked
        self.name = name or network.name

    @property
    def n_features(self) -> int:
        return self.network.n_in - self.network.n_out

    def probabilities(self, canonical, features) -> np.ndarray:
        return self.network(np.column_stack([canonical, features]))

    def knockouts(self, canonical, features) -> np.ndarray:
        return self.probabilities(canonical, features) > self.thresholds

    def apply(self, canonical, features) -> np.ndarray:
        """g_n: the canonical measurements with knocked-out entries at their knocked value."""
        return np.where(self.knockouts(canonical, features), self.knocked, canonical)

    def save(self, network_path, parameters_path) -> None:
        """The classifier as ONNX, thresholds and knocked values as ``.npz``."""
        from percver.formats import save_network

        save_network(self.network, network_path)
        np.savez(parameters_path, thresholds=self.thresholds, knocked=self.knocked)

    @classmethod
    def load(cls, network_path, parameters_path) -> "KnockoutModel":
        from percver.formats import load_network

        parameters_path = Path(parameters_path)
        if not parameters_path.is_file():
            raise MissingFileError(f"knock-out parameters file not found: {parameters_path}")
        with np.load(parameters_path) as saved:
            missing = sorted({"thresholds", "knocked"} - set(saved.files))
            if missing:
                raise InputError(f"'{parameters_path}' lacks {missing}; save it with KnockoutModel.save")
            return cls(load_network(network_path), saved["thresholds"], saved["knocked"], Path(network_path).stem)

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.name!r}, {self.network!r})"


def train_knockout(
    inputs,
    labels,
    hidden=(64, 64),
    *,
    knocked,
    epochs: int = 200,
    batch: int = 128,
    lr: float = 3e-3,
    positive_weight: float = POSITIVE_WEIGHT,
    threshold_gains=None,
    seed: int = 0,
    threads: int | None = None,
    progress: bool = False,
    name: str = "knockout",
) -> KnockoutModel:
    """Train c_n on ``inputs`` (N x (m + features): canonical measurements, then state features)
    and ``labels`` (N x m); thresholds fitted on the same data, for accuracy (the paper's choice)
    or, given ``threshold_gains`` (N x m: the error knocking out each entry removes, negative
    where it adds error), for the largest total gain."""
    torch = training.require_torch()
    inputs, labels = np.asarray(inputs, dtype=float), np.asarray(labels, dtype=float)
    if labels.ndim != 2 or inputs.ndim != 2 or len(inputs) != len(labels) or inputs.shape[1] < labels.shape[1]:
        raise InputError(f"knock-out training needs inputs N x (m + features) and labels N x m, got {inputs.shape} and {labels.shape}")
    training.session(torch, seed, threads)
    module = training.mlp(torch, (inputs.shape[1], *hidden, labels.shape[1]), torch.nn.Tanh)
    # The sigmoid is folded into the loss for stability and appended for export.
    loss = torch.nn.BCEWithLogitsLoss(pos_weight=torch.tensor(positive_weight))
    training.fit(
        torch, module, inputs, labels, loss, epochs=epochs, batch=batch, lr=lr, weight_decay=0.0, seed=seed, progress=progress, desc=name
    )
    module.append(torch.nn.Sigmoid())
    network = training.to_network(module, name, inputs=inputs)
    probabilities = network(inputs)
    if threshold_gains is None:
        thresholds = fit_thresholds(probabilities, labels > 0.5)
    else:
        gains = np.asarray(threshold_gains, dtype=float)
        thresholds = fit_thresholds(probabilities, gains > 0, weights=np.abs(gains))
    return KnockoutModel(network, thresholds, knocked, name)
