"""Learned noise models (paper, sections 4.1-4.2), trained with torch and exported to ONNX.

- :mod:`~percver.noise.knockout`: knock-out classifiers for adversarial noise (entries that
  jump to a knocked value, e.g. LiDAR rays swallowed by a reflective panel);
- :mod:`~percver.noise.generative`: generative models for benign noise ((canonical, noise
  parameter or state features) -> measurement, e.g. image contrast);
- :mod:`~percver.noise.denoiser`: denoisers h_d (measured -> canonical measurements, a network stage);
- :mod:`~percver.noise.thresholds`: labels by t_Delta and per-output probability thresholds;
- :mod:`~percver.noise.training`: the lazy torch import, dense modules, the training loop and
  the conversion to :class:`percver.Network` (``pv.save_network`` writes files ``pv.load_network`` reads).

Training needs torch (``pip install "percver[train]"``); trained models evaluate with numpy.
"""

from percver.noise.denoiser import Denoiser, train_denoiser
from percver.noise.generative import GenerativeModel, train_generative
from percver.noise.knockout import KnockoutModel, train_knockout
from percver.noise.thresholds import ThresholdCurve, fit_thresholds, label, noised, replacements, threshold_curve
from percver.noise.training import require_torch, to_network

__all__ = [
    "Denoiser",
    "GenerativeModel",
    "KnockoutModel",
    "ThresholdCurve",
    "fit_thresholds",
    "label",
    "noised",
    "replacements",
    "require_torch",
    "threshold_curve",
    "to_network",
    "train_denoiser",
    "train_generative",
    "train_knockout",
]
