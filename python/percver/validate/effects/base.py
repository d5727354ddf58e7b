"""The effect protocol: a named, parametrised physical mechanism that a model may be missing."""

from __future__ import annotations

import inspect
from typing import ClassVar

import numpy as np

from percver.errors import InputError


class Effect:
    """Base of every effect.

    A subclass names its parameters with their neutral values in ``defaults`` and gives
    ``bounds`` for those that are fitted (others, like the state a drag acts on, are chosen
    when the candidate is made). ``smooth`` effects are fitted by robust least squares,
    the others (thresholds, regions, delays) by a grid that is refined around its best point.
    A stochastic effect does not change the expected measurement: it is fitted by maximum
    likelihood on the residuals and explains entries through ``accounts``. ``stage`` places
    the effect in the physical chain (lighting before motion blur before the lens), since
    effects do not commute; within a stage, effects apply in the order added.
    """

    name: ClassVar[str] = "effect"
    kinds: ClassVar[tuple] = ()
    defaults: ClassVar[dict] = {}
    bounds: ClassVar[dict] = {}
    units: ClassVar[dict] = {}
    smooth: ClassVar[bool] = True
    stochastic: ClassVar[bool] = False
    stage: ClassVar[int] = 0
    repeatable: ClassVar[bool] = False
    moves_sensor: ClassVar[bool] = False

    def __init__(self, **params):
        unknown = sorted(set(params) - set(self.defaults))
        if unknown:
            raise InputError(f"effect '{self.name}' has no parameter {unknown}; its parameters are {list(self.defaults)}")
        self.params = {**self.defaults, **params}

    def replace(self, **params) -> "Effect":
        return type(self)(**{**self.params, **params})

    @classmethod
    def cause(cls) -> str:
        """The physical cause this effect stands for (the first paragraph of its docstring)."""
        return inspect.cleandoc(cls.__doc__ or "").split("\n\n")[0].replace("\n", " ").replace("``", "")

    @classmethod
    def variants(cls, model) -> list:
        """Unfitted candidates of this effect for ``model`` (one per velocity state for drags)."""
        return [cls()]

    def applicable(self, model, evaluation) -> bool:
        return True

    def search_bounds(self, model, evaluation) -> dict:
        """Bounds of the fitted parameters; some depend on the data's scale."""
        return dict(self.bounds)

    def search_width(self, model, evaluation) -> dict:
        """Width of the first grid of a non-smooth search, per parameter (whole range by default)."""
        return {}

    def starts(self, model, evaluation, predicted) -> list:
        """Starting points (dicts of parameters) for the fit; data-driven where that helps."""
        return [{}]

    # stochastic effects ----------------------------------------------------------------
    def fit_stochastic(self, model, evaluation, predicted) -> "Effect":
        raise NotImplementedError

    def sample(self, values, rng, model):
        raise NotImplementedError

    def accounts(self, predicted, measured, model) -> np.ndarray:
        return np.zeros(measured.shape, dtype=bool)

    def __repr__(self) -> str:
        shown = ", ".join(f"{k}={_short(v)}" for k, v in self.params.items())
        return f"{self.name}({shown})"

    def __eq__(self, other) -> bool:
        return type(other) is type(self) and other.params == self.params

    def __hash__(self) -> int:
        return hash((self.name, tuple(sorted((k, repr(v)) for k, v in self.params.items()))))


# Second moment of a standard normal restricted to its central 90%: rescales a trimmed variance.
_TRIMMED_MOMENT = 0.6226


def robust_sigma(values) -> float:
    """Standard deviation of the Gaussian core of ``values``: the RMS of the central 90%
    about the median, rescaled. Unlike the median absolute deviation it stays sensible
    when many values sit exactly on a bound (pixels clipped at black)."""
    values = np.asarray(values, dtype=float).ravel()
    if values.size == 0:
        return 0.0
    spread = np.abs(values - np.median(values))
    core = spread[spread <= np.quantile(spread, 0.9)]
    return float(np.sqrt(np.mean(core**2) / _TRIMMED_MOMENT))


def _short(value):
    return f"{value:.4g}" if isinstance(value, float) else repr(value)


class GaussianNoise(Effect):
    """Measurement noise: independent Gaussian noise of standard deviation ``sigma`` on every value.

    White noise cannot be predicted, so it removes no error; its fitted ``sigma`` is the
    noise floor left once systematic effects are modelled, and ``sample`` reproduces it.
    ``sigma`` is fitted robustly (``robust_sigma``), so that errors no effect explains (a ghost
    obstacle) do not pass for noise.
    """

    name = "gaussian_noise"
    kinds = ("lidar", "image", "generic")
    defaults = {"sigma": 0.0}
    bounds = {"sigma": (0.0, np.inf)}
    stochastic = True
    stage = 9

    def fit_stochastic(self, model, evaluation, predicted):
        residual = (evaluation.measured - predicted)[~model.accounted(predicted, evaluation.measured)]
        return self.replace(sigma=robust_sigma(residual))

    def sample(self, values, rng, model):
        noisy = values + rng.normal(0.0, self.params["sigma"], values.shape)
        if model.kind == "lidar":
            # A ray without an echo reads the range limit whatever the noise of the echoes.
            noisy = np.where(values >= model.range_limit(), values, noisy)
        return model.clip(noisy)
