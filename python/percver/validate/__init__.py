"""Model validation: compare a model with measurements, see where it fails, name the missing effect.

``compare(model, data)`` gives a ``Report`` (errors, ``where()``, ``explain()``, HTML/JSON);
``diagnose(model, data)`` adds effects from ``effects`` until none helps on held-out data.
Models: ``percver.sensors.lidar.canonical(...)``, ``percver.sensors.camera.ImageModel``, ``DynamicsModel`` around
any plant (``FunctionPlant``, ``pv.Discrete``, ``pv.Continuous``), or ``FunctionSensor`` around
any function (a ``Network``, an ``Expr`` evaluator). ``diagnose(..., learn=True)`` ends with a
learned noise model (``percver.validate.learned``) where effects leave a localized residual.
"""

from percver.validate import effects
from percver.validate.diagnose import Diagnosis, Step, diagnose
from percver.validate.fitting import Candidate, Ranking, fit_effect, refit
from percver.validate.models import (
    DynamicsModel,
    Evaluation,
    FunctionPlant,
    FunctionSensor,
    Model,
    Plant,
    SensorModel,
    SystemPlant,
    as_model,
)
from percver.validate.report import Dimension, Region, Report, Where, compare

__all__ = [
    "compare",
    "diagnose",
    "effects",
    "Report",
    "Where",
    "Region",
    "Dimension",
    "Diagnosis",
    "Step",
    "Candidate",
    "Ranking",
    "fit_effect",
    "refit",
    "Model",
    "SensorModel",
    "FunctionSensor",
    "DynamicsModel",
    "FunctionPlant",
    "Plant",
    "SystemPlant",
    "Evaluation",
    "as_model",
]
