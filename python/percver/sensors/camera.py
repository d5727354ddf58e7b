"""A camera as a canonical sensor model g_c: any renderer of the state into images, with the
image effects (contrast, motion blur, ...) that validation fits on top of it.

The renderer is the user's (a first-principles scene such as gymnasium's, a learned generator
``Network``, pixel expressions, a simulator); this module adds what every camera shares: the
pixel grid, the state whose motion blurs the image, and cached renders while effects are fitted.
A diagnosed camera can be verified when its renderer is a ``Network`` of the states or a list
of expressions (``percver.validate.verifiable.camera_component``); a Python function cannot.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from percver.errors import InputError
from percver.validate.models import BatchCache, SensorModel


class ExpressionRenderer:
    """A renderer given as one expression per pixel (row-major) of the named states."""

    def __init__(self, exprs, state_names):
        from percver.expr import as_expr

        self.exprs = [as_expr(e) for e in exprs]
        self.state_names = tuple(state_names)
        unknown = sorted({n for e in self.exprs for n in e.variables()} - set(self.state_names))
        if unknown:
            raise InputError(f"the camera's pixel expressions use {unknown}, which are not its states {list(self.state_names)}")

    def __call__(self, states):
        from percver.expr import evaluate

        states = np.asarray(states, dtype=float)
        return evaluate(self.exprs, dict(zip(self.state_names, states.T))).reshape(len(states), -1)


class ImageModel(SensorModel):
    """A camera: ``render(states) -> images`` (N x H x W in [0, 1], or flattened rows).

    ``render`` is a function, a ``Network`` (a generator: the states in ``state_names`` order
    to the H x W pixels) or a list of H x W expressions of the states (row-major); the last two
    have a set form, so that ``diagnosis.model`` can be verified. ``position`` names the state
    whose shift blurs the image (the paper's motion blur overlays renders at ``position -/+
    delta``); the first state by default.
    """

    kind = "image"

    def __init__(self, render: Callable, state_names, shape, *, position: str | None = None, effects=()):
        self.shape = tuple(int(s) for s in shape)
        if len(self.shape) != 2:
            raise InputError(f"image shape must be (height, width), got {shape}")
        names = [f"px{r}_{c}" for r in range(self.shape[0]) for c in range(self.shape[1])]
        super().__init__(state_names, names, effects)
        self.render = _renderer(render, self.state_names, len(names))
        # Three renders (centre and the blur's two overlays) for the data and each fold.
        self._cache = BatchCache(size=12)
        self.position = position or self.state_names[0]
        if self.position not in self.state_names:
            raise InputError(f"position '{self.position}' is not a state of the model {list(self.state_names)}")

    def images(self, states, effects=None, *, shift: float = 0.0) -> np.ndarray:
        """Images (N x H x W) in ``states`` after ``effects`` (the model's deterministic ones by default).

        ``shift`` moves the ``position`` state first (the blur's overlays); the renders of
        shifted states are cached too, so that fitting other effects under a fixed blur
        does not render again.
        """
        states = np.asarray(states, dtype=float)
        images = self._cache.get(states, shift, lambda: self._render(self._moved(states, shift)))
        states = self._moved(states, shift)
        stack = self.deterministic_effects if effects is None else effects
        for i, effect in enumerate(stack):
            images = effect.apply(images, states, self, stack[:i])
        return images

    def _moved(self, states, shift):
        if not shift:
            return states
        moved = states.copy()
        moved[:, self.state_names.index(self.position)] += shift
        return moved

    def _render(self, states):
        return np.asarray(self.render(states), dtype=float).reshape((len(states),) + self.shape)

    def predict_inputs(self, inputs):
        return self.images(inputs["states"]).reshape(len(inputs["states"]), -1)

    def clip(self, values):
        return np.clip(values, 0.0, 1.0)


def _renderer(render, state_names, pixels):
    """``render`` as a function of the states, checked against the image size where it can be."""
    from percver.networks import Network

    if isinstance(render, (list, tuple)):
        render = ExpressionRenderer(render, state_names)
        count = len(render.exprs)
    elif isinstance(render, Network):
        if render.n_in != len(state_names):
            raise InputError(
                f"the camera's generator network '{render.name}' takes {render.n_in} inputs; it must take the camera's states "
                f"{list(state_names)} (give ImageModel the states the network reads, in its order)"
            )
        count = render.n_out
    elif callable(render):
        return render
    else:
        raise InputError(f"a camera's render must be a function, a Network or a list of pixel expressions, got {type(render).__name__}")
    if count != pixels:
        raise InputError(f"the camera's renderer gives {count} pixels, its shape {pixels} (height x width)")
    return render
