"""The F1/10 car with LiDAR under adversarial noise (paper, section 5.2 and Appendix B).

- ``world``: the square loop and the single right turn, hallway-local coordinates (y1, y2, y4),
  the controllers' 21-ray view, and the canonical scan as expressions (``scan_exprs``);
- ``dynamics``: the bicycle model (numpy RK4 and ``Expr`` vector field);
- ``controllers``: the 12 controller networks with the car's input/output conventions;
- ``simulate``: the "real" hall with reflective surfaces and the recorded runs;
- ``estimate``: the particle filter that gives every scan a pose;
- ``noise``: t_Delta labels, the knock-out classifier c_n, the denoiser h_d (torch -> ONNX);
- ``pipeline``: the training set D, the paper's metrics, simulation with a noise model;
- ``plots``, ``study``: figures and the file-to-file stages of ``percver cases f1tenth``;
- ``verification``: the Table 1 loop and property, ``verify(y1=(lo, hi), networks=...)`` and its row.
"""

from percver.cases.f1tenth import controllers, data, dynamics, loop, noise, pipeline, simulate, verification, world
from percver.cases.f1tenth.controllers import Controller
from percver.cases.f1tenth import particle_filter
from percver.cases.f1tenth.particle_filter import FilterSettings, estimate_poses
from percver.cases.f1tenth.noise import Denoiser, NoiseModel
from percver.cases.f1tenth.pipeline import TrainingSet, training_set
from percver.cases.f1tenth.simulate import RealWorld
from percver.cases.f1tenth.verification import verify
from percver.cases.f1tenth.world import from_local, right_turn, scan_exprs, square, to_local

__all__ = [
    "controllers",
    "data",
    "dynamics",
    "loop",
    "noise",
    "particle_filter",
    "pipeline",
    "simulate",
    "verification",
    "world",
    "Controller",
    "FilterSettings",
    "estimate_poses",
    "Denoiser",
    "NoiseModel",
    "TrainingSet",
    "training_set",
    "RealWorld",
    "from_local",
    "right_turn",
    "scan_exprs",
    "square",
    "to_local",
    "verify",
]
