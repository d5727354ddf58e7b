"""Camera effects on images (N x H x W, values in [0, 1]), each also as expressions of the
pixels (``image_expr``): the set form ``verify`` uses for a diagnosed camera."""

from __future__ import annotations

import math

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

    def image_expr(self, pixels, p, model, render):
        """The effect on one image as expressions (row-major pixels), sound over sets of states and
        of the parameters ``p`` (numbers or ``pv.uncertain``); ``render(shift)`` is the image of the
        effects before this one with the ``position`` state moved by ``shift`` (for the blur)."""
        from percver.validate.verifiable import NoSetSemanticsError

        raise NoSetSemanticsError(
            f"the camera effect '{self.name}' has no expression form, so a diagnosed camera with it cannot be "
            "verified: leave it out of diagnose (effects=[...]) and bound what it leaves with "
            "diagnosis.system(residual='max'), or give the effect an image_expr"
        )


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

    def image_expr(self, pixels, p, model, render):
        from percver.expr import clip

        mean = _total(pixels) / len(pixels)
        return [clip(mean + p["factor"] * (x - mean), 0.0, 1.0) for x in pixels]


class Brightness(ImageEffect):
    """Exposure: every pixel is scaled by ``factor`` (PIL's ``ImageEnhance.Brightness``)."""

    name = "brightness"
    stage = 1
    defaults = {"factor": 1.0}
    bounds = {"factor": (0.0, 3.0)}

    def apply(self, images, states, model, before):
        return np.clip(self.params["factor"] * images, 0.0, 1.0)

    def image_expr(self, pixels, p, model, render):
        from percver.expr import clip

        return [clip(p["factor"] * x, 0.0, 1.0) for x in pixels]


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

    def image_expr(self, pixels, p, model, render):
        """The overlay of the renders at position -/+ delta, rescaled by its smallest and largest
        pixel (a set that cannot tell the two apart gets the hull of both, so the rescaled image
        is loose where the image may be nearly flat)."""
        from percver.expr import maximum, minimum

        delta = p["delta"]
        overlay = [0.5 * a + c + 0.5 * b for a, c, b in zip(render(-delta), pixels, render(delta))]
        low, high = _reduce(minimum, overlay), _reduce(maximum, overlay)
        span = high - low
        return [(o - low) / span for o in overlay]


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

    def image_expr(self, pixels, p, model, render):
        h, w = model.shape
        grid = [pixels[r * w : (r + 1) * w] for r in range(h)]
        columns = [_shift_expr(list(column), p["rows"]) for column in zip(*grid)]
        grid = [_shift_expr(list(row), p["cols"]) for row in zip(*columns)]
        return [x for row in grid for x in row]


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


def _shift_expr(line, amount):
    """``_shift`` of one line of pixel expressions: pixel i is the tent-weighted sum over whole
    moves k of pixel i - k (edges repeated), weight max(0, 1 - |amount - k|): for a number the
    two neighbours of ``_shift``, for a range every move it may take."""
    from percver.expr import abs_, maximum

    size = len(line)
    lo, hi = _range(amount)
    weights = []
    for k in range(math.floor(lo), math.floor(hi) + 2):
        if isinstance(amount, (int, float)):
            if abs(amount - k) < 1:
                weights.append((k, 1.0 - abs(amount - k)))
        else:
            weights.append((k, maximum(0.0, 1.0 - abs_(amount - k))))
    return [_total([weight * line[min(max(i - k, 0), size - 1)] for k, weight in weights]) for i in range(size)]


def _range(value) -> tuple:
    """The interval of a number or of an expression of uncertain parameters alone."""
    from percver._core import eval_interval
    from percver.expr import as_expr

    if isinstance(value, (int, float)):
        return float(value), float(value)
    return eval_interval([as_expr(value)], [], [])[0]


def _total(terms):
    """The sum of expressions as a balanced tree (shallow for images of hundreds of pixels)."""
    return _reduce(lambda a, b: a + b, terms)


def _reduce(f, terms):
    terms = list(terms)
    while len(terms) > 1:
        terms = [f(terms[i], terms[i + 1]) if i + 1 < len(terms) else terms[i] for i in range(0, len(terms), 2)]
    return terms[0]


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

    def image_expr(self, pixels, p, model, render):
        """Saturated where the disc covers the pixel for every parameter in range, unchanged where
        it covers it for none, and anything between (a disturbance in [0, 1] mixing the two) where
        that depends on the parameters: no branch per pixel."""
        from percver.expr import as_expr, uncertain

        h, w = model.shape
        out = []
        for (r, c), x in zip(np.ndindex(h, w), pixels):
            lo, hi = _range(as_expr((r - p["row"]) ** 2 + (c - p["col"]) ** 2 - p["radius"] ** 2))
            out.append(1.0 if hi <= 0 else x if lo > 0 else x + (1.0 - x) * uncertain(0.0, 1.0))
        return out


EFFECTS = (Contrast, Brightness, Blur, Shift, Glare)
