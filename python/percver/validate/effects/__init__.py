"""The effect library: named physical mechanisms that a canonical model may be missing.

Every effect has parameters with bounds, a fitting method (robust least squares for smooth
effects, a refined grid for thresholds, regions and delays, maximum likelihood for noise)
and a docstring naming its physical cause. ``library(kind)`` lists them per model kind;
``get(name, **params)`` builds one, e.g. ``get("range_bias", bias=0.05)``.

LiDAR: range_bias, range_scale, angle_offset, position_offset, max_range,
specular_reflection, dropout, gaussian_noise. Camera: contrast, brightness, blur, shift,
glare, gaussian_noise. Dynamics: linear_drag, quadratic_drag, coulomb_friction,
actuator_gain, actuator_bias, actuator_saturation, actuator_delay.
"""

from __future__ import annotations

from percver.errors import InputError
from percver.validate.effects import camera, dynamics, lidar
from percver.validate.effects.base import Effect, GaussianNoise
from percver.validate.effects.camera import Blur, Brightness, Contrast, Glare, Shift
from percver.validate.effects.dynamics import (
    ActuatorBias,
    ActuatorDelay,
    ActuatorGain,
    ActuatorSaturation,
    CoulombFriction,
    LinearDrag,
    QuadraticDrag,
)
from percver.validate.effects.lidar import (
    AngleOffset,
    Dropout,
    MaxRange,
    PositionOffset,
    RangeBias,
    RangeScale,
    SpecularReflection,
)

ALL = lidar.EFFECTS + camera.EFFECTS + dynamics.EFFECTS + (GaussianNoise,)
LIBRARY = {cls.name: cls for cls in ALL}


def library(kind: str | None = None) -> list:
    """Effect classes that apply to models of ``kind`` ("lidar", "image", "dynamics"), or all."""
    return [cls for cls in ALL if kind is None or kind in cls.kinds]


def get(name: str, **params) -> Effect:
    """The effect called ``name`` with ``params`` (the others at their neutral values)."""
    if name not in LIBRARY:
        raise InputError(f"unknown effect '{name}'; the library has {sorted(LIBRARY)}")
    return LIBRARY[name](**params)


def candidates(model, evaluation, effects=None) -> list:
    """Unfitted candidate effects for ``model``: the library of its kind, or ``effects`` (names,
    classes or instances). Effects already in the model are left out unless repeatable."""
    if effects is None:
        pool = [variant for cls in library(model.kind) for variant in cls.variants(model)]
    else:
        pool = []
        for effect in effects:
            if isinstance(effect, str):
                effect = LIBRARY.get(effect) or get(effect)
            pool.extend(effect.variants(model) if isinstance(effect, type) else [effect])
        wrong = [e.name for e in pool if model.kind not in e.kinds]
        if wrong:
            raise InputError(f"effects {wrong} do not apply to a {model.kind} model")
    present = {(e.name, e.params.get("state")) for e in model.effects}
    return [e for e in pool if (e.repeatable or (e.name, e.params.get("state")) not in present) and e.applicable(model, evaluation)]


__all__ = [
    "Effect",
    "library",
    "get",
    "candidates",
    "LIBRARY",
    "GaussianNoise",
    "RangeBias",
    "RangeScale",
    "AngleOffset",
    "PositionOffset",
    "MaxRange",
    "SpecularReflection",
    "Dropout",
    "Contrast",
    "Brightness",
    "Blur",
    "Shift",
    "Glare",
    "LinearDrag",
    "QuadraticDrag",
    "CoulombFriction",
    "ActuatorGain",
    "ActuatorBias",
    "ActuatorSaturation",
    "ActuatorDelay",
]
