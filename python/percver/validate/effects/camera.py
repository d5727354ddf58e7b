"""Camera effects on images (N x H x W, values in [0, 1])."""

from __future__ import annotations

import numpy as np
from percver.validate.effects.base import Effect


class ImageEffect(Effect):
    """Base of image effects: ``apply(images, states, model, before)`` maps images to images.

    ``before`` is the stack of effects applied so far, for effects (blur) that must render
    other states through the same stack.
    """

    kinds = ("image",)

    def apply(self, images, states, model, before):
        raise NotImplementedError


class Contrast(ImageEffect):
    """Lighting contrast: pixel values move away from (``factor`` > 1) or towards (< 1) the image's
    mean grey, as PIL's ``ImageEnhance.Contrast`` does (0 gives a flat grey image).

    Unlike PIL, no 8-bit rounding, so that the factor fits smoothly; the Mountain Car training data
    (``percver.cases.mountain_car.contrast``) calls PIL itself, as the paper did."""

    name = "contrast"
    stage = 1
    defaults = {"factor": 1.0}
    bounds = {"factor": (0.0, 3.0)}

    def apply(self, images, states, model, before):
        mean = images.mean(axis=(1, 2), keepdims=True)
        return np.clip(mean + self.params["factor"] * (images - mean), 0.0, 1.0)


class Brightness(ImageEffect):
    """Exposure: every pixel is scaled by ``factor`` (PIL's ``ImageEnhance.Brightness``)."""

    name = "brightness"
    stage = 1
    defaults = {"factor": 1.0}
    bounds = {"factor": (0.0, 3.0)}

    def apply(self, images, states, model, before):
        return np.clip(self.params["factor"] * images, 0.0, 1.0)


class Blur(ImageEffect):
    """Motion blur as in the paper: lighter copies of the scene at position -/+ ``delta`` overlay the
    image (0.5, 1, 0.5 weights), then the image is rescaled to [0, 1].

    Fitted on a refined grid, not by least squares: a rasterised scene (gymnasium's Mountain
    Car) moves in whole pixels, so at the scale of a finite-difference step the error is a
    staircase in ``delta`` whose flat treads stall a gradient method near its start (a blur of
    0.1 was fitted as 0.087 that way; the grid finds it to 1e-4)."""

    name = "blur"
    stage = 2
    defaults = {"delta": 0.0}
    bounds = {"delta": (0.0, np.inf)}
    smooth = False

    def search_bounds(self, model, evaluation):
        column = model.state_names.index(model.position)
        span = np.ptp(evaluation.states[:, column])
        return {"delta": (0.0, 0.25 * span if span > 0 else 1.0)}

    def starts(self, model, evaluation, predicted):
        hi = self.search_bounds(model, evaluation)["delta"][1]
        return [{"delta": hi * f} for f in (0.05, 0.2, 0.5)]

    def apply(self, images, states, model, before):
        delta = self.params["delta"]
        left, right = (model.images(states, before, shift=sign * delta) for sign in (-1.0, 1.0))
        return motion_blur(left, images, right)


def motion_blur(left, centre, right):
    """The paper's blur (Appendix A.3) of image stacks (N x H x W): ``0.5 left + centre + 0.5 right``,
    each image then rescaled to [0, 1] (a flat image stays as it is, shifted to 0).

    ``left`` and ``right`` are the scene rendered at position ``-/+ delta``. The Mountain Car case
    study builds its training data with this function too, so fitted and generated blur agree.
    """
    overlay = 0.5 * np.asarray(left) + np.asarray(centre) + 0.5 * np.asarray(right)
    low = overlay.min(axis=(-2, -1), keepdims=True)
    span = overlay.max(axis=(-2, -1), keepdims=True) - low
    return (overlay - low) / np.where(span > 0, span, 1.0)


class Shift(ImageEffect):
    """Camera misalignment: the image moves by ``rows`` and ``cols`` pixels (bilinear, edges repeated)."""

    name = "shift"
    stage = 3
    defaults = {"rows": 0.0, "cols": 0.0}
    bounds = {"rows": (-3.0, 3.0), "cols": (-3.0, 3.0)}
    units = {"rows": "px", "cols": "px"}

    def apply(self, images, states, model, before):
        return _shift(_shift(images, self.params["rows"], 1), self.params["cols"], 2)


def _shift(images, amount, axis):
    """Move content by ``amount`` pixels along ``axis``: linear interpolation, edge pixels repeated."""
    whole = int(np.floor(amount))
    fraction = amount - whole
    size = images.shape[axis]
    source = np.arange(size) - whole
    near = np.take(images, np.clip(source, 0, size - 1), axis=axis)
    if fraction == 0:
        return near
    far = np.take(images, np.clip(source - 1, 0, size - 1), axis=axis)
    return (1 - fraction) * near + fraction * far


def _washed_out(predicted, measured):
    return (measured >= 0.95) & (predicted < 0.75)


class Glare(ImageEffect):
    """Glare: a disc of ``radius`` pixels around (``row``, ``col``) is saturated (white)."""

    name = "glare"
    stage = 4
    defaults = {"row": 0.0, "col": 0.0, "radius": 0.0}
    bounds = {"row": (0.0, np.inf), "col": (0.0, np.inf), "radius": (0.0, np.inf)}
    units = {"row": "px", "col": "px", "radius": "px"}
    smooth = False
    repeatable = True

    def search_bounds(self, model, evaluation):
        h, w = model.shape
        return {"row": (0.0, h - 1.0), "col": (0.0, w - 1.0), "radius": (0.0, max(h, w) / 2)}

    def search_width(self, model, evaluation):
        return {"row": 4.0, "col": 4.0, "radius": 4.0}

    def applicable(self, model, evaluation):
        """Only pixels that read saturated where the model sees them darker can be glare."""
        predicted = model.predict_inputs(evaluation.inputs)
        return bool(np.any(_washed_out(predicted, evaluation.measured)))

    def starts(self, model, evaluation, predicted):
        """Centre the disc on the pixels that read saturated most often where darker was predicted."""
        brighter = _washed_out(predicted, evaluation.measured).mean(axis=0).reshape(model.shape)
        bright = brighter >= 0.5 * brighter.max()
        rows, cols = np.nonzero(bright)
        return [{"row": float(rows.mean()), "col": float(cols.mean()), "radius": float(np.sqrt(bright.sum() / np.pi))}]

    def apply(self, images, states, model, before):
        h, w = model.shape
        r, c = np.mgrid[0:h, 0:w]
        disc = (r - self.params["row"]) ** 2 + (c - self.params["col"]) ** 2 <= self.params["radius"] ** 2
        return np.where(disc, 1.0, images)


EFFECTS = (Contrast, Brightness, Blur, Shift, Glare)
