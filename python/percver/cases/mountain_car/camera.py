"""The canonical camera g_c of Mountain Car (paper, Appendix A.1): gymnasium's scene with the
paper's enlarged car, rendered at 20 x 30, and the benign noise the paper applies to it (contrast,
blur).

Images are 20 x 30 (row-major when flattened to the 600 inputs of the networks), values in [0, 1],
the car bright on a dark background as in the authors' networks.
"""

from __future__ import annotations

import os

import numpy as np

from percver.errors import InputError, MissingDependencyError
from percver.validate.effects.camera import motion_blur

HEIGHT, WIDTH = 20, 30
SHAPE = (HEIGHT, WIDTH)
PIXELS = HEIGHT * WIDTH

# gymnasium's screen, and the quarter-size screen on which its fixed-size car (40 x 20 px, wheels of
# radius 8) is 4x as large relative to the world; MARGIN extra rows keep the top of a car near the
# goal that the clearance shift (below) moves back into the frame.
FULL = (400, 600)
ENLARGE = 4
MARGIN = 8
# gymnasium lifts the car 10 px above the track; on the quarter screen that is 40 full-size px.
CLEARANCE = 10
LUMA = np.array([0.299, 0.587, 0.114])  # ITU-R 601, as PIL's convert("L")
OFF_SCREEN = 10.0  # a position whose car is drawn right of the screen: the scene without the car
RENDER_LIMIT = 5.0


def _gymnasium():
    os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # pygame without a display
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    try:
        import gymnasium
    except ImportError:
        raise MissingDependencyError("rendering Mountain Car images needs gymnasium and pygame: pip install 'percver[cases]'") from None
    return gymnasium


def _area_weights(n_out: int, out_size: float, n_in: int, in_size: float, offset: float) -> np.ndarray:
    """(n_out, n_in) weights of area averaging: input cell i spans [i, i + 1) * in_size + offset and
    output cell o spans [o, o + 1) * out_size, in the same (full-resolution pixel) units."""
    lo_in = np.arange(n_in) * in_size + offset
    lo_out = np.arange(n_out) * out_size
    overlap = np.minimum(lo_out[:, None] + out_size, lo_in[None, :] + in_size) - np.maximum(lo_out[:, None], lo_in[None, :])
    return np.clip(overlap, 0.0, None) / out_size


class Camera:
    """Canonical images of gymnasium's ``MountainCarContinuous-v0`` with the paper's enlarged car.

    The paper renders the 400 x 600 scene with a car about 4x larger than gymnasium's and
    downsamples it to 20 x 30. gymnasium draws the car in fixed pixel sizes, so on a 100 x 150
    screen it is 4x larger relative to the world; the track and the goal flag there would be 4x
    thicker too. Each image therefore combines two headless gymnasium renders (``render_mode=
    "rgb_array"``): the scene without the car at 400 x 600 (drawn once), and the car alone (a
    quarter-size render minus the same render without the car) scaled 4x and moved 30 px down, so
    that the car keeps gymnasium's 10 px clearance above the track instead of 40. Then grey
    (ITU-R 601 luma), inverted (car bright, as the authors' networks have it) and area-averaged to
    20 x 30. Against the authors' generator this gives a mean absolute pixel difference of 0.012,
    and the authors' estimator reads these images with a mean error of 0.019 (0.013 on its own
    generator's images): their networks can be evaluated on our images.
    """

    def __init__(self):
        gym = _gymnasium()
        quarter = (FULL[0] // ENLARGE + MARGIN, FULL[1] // ENLARGE)
        self._full = self._env(gym, FULL)
        self._quarter = self._env(gym, quarter)
        rows = _area_weights(HEIGHT, FULL[0] / HEIGHT, FULL[0], 1.0, 0.0)
        cols = _area_weights(WIDTH, FULL[1] / WIDTH, FULL[1], 1.0, 0.0)
        self._background = rows @ self._render(self._full, OFF_SCREEN) @ cols.T
        # quarter row q covers full rows [4q, 4q + 4) of the taller frame; after the shift down and the
        # crop of the margin it starts at 4q + shift - 4 * MARGIN.
        shift = ENLARGE * CLEARANCE - CLEARANCE
        self._rows = _area_weights(HEIGHT, FULL[0] / HEIGHT, quarter[0], ENLARGE, shift - ENLARGE * MARGIN)
        self._cols = _area_weights(WIDTH, FULL[1] / WIDTH, quarter[1], ENLARGE, 0.0)
        self._empty = self._render(self._quarter, OFF_SCREEN)

    @staticmethod
    def _env(gym, size):
        env = gym.make("MountainCarContinuous-v0", render_mode="rgb_array").unwrapped
        env.screen_height, env.screen_width = size
        return env

    @staticmethod
    def _render(env, position: float) -> np.ndarray:
        """Inverted grey image in [0, 1] of the car at ``position`` (velocity does not show)."""
        env.state = np.array([position, 0.0])
        return 1.0 - (env.render() @ LUMA) / 255.0

    def render(self, positions, *, progress: bool = False) -> np.ndarray:
        """Canonical images (n, 20, 30) of the car at ``positions`` (any position; the car may leave the frame)."""
        positions = _positions(positions)
        out = np.empty((len(positions),) + SHAPE)
        iterator = positions
        if progress:
            from tqdm import tqdm

            iterator = tqdm(positions, desc="render", unit="img")
        for i, p in enumerate(iterator):
            car = self._render(self._quarter, float(p)) - self._empty
            out[i] = self._background + self._rows @ car @ self._cols.T
        return np.clip(out, 0.0, 1.0)

    def observe(self, positions, delta_c=None, delta_b=None) -> np.ndarray:
        """The true images (n, 20, 30) of the paper's noise: canonical, contrast ``delta_c``, blur ``delta_b``,
        or both (composite: the blur of the contrasted scene, i.e. contrast applied to each of the three
        renders, as lighting acts before motion blur). Noise parameters are numbers or one per position."""
        positions = _positions(positions)

        def scene(at):
            images = self.render(at)
            return images if delta_c is None else contrast(images, delta_c)

        if delta_b is None:
            return scene(positions)
        delta_b = _per_image(delta_b, len(positions), "delta_b")
        return motion_blur(scene(positions - delta_b), scene(positions), scene(positions + delta_b))


_CAMERA: Camera | None = None


def camera() -> Camera:
    """The shared :class:`Camera` (gymnasium environments are made once per process)."""
    global _CAMERA
    if _CAMERA is None:
        _CAMERA = Camera()
    return _CAMERA


def render(positions, *, progress: bool = False) -> np.ndarray:
    """Canonical images (n, 20, 30) at ``positions``; see :class:`Camera`."""
    return camera().render(positions, progress=progress)


def observe(positions, delta_c=None, delta_b=None) -> np.ndarray:
    """True images under contrast and/or blur; see :meth:`Camera.observe`."""
    return camera().observe(positions, delta_c, delta_b)


def _positions(positions) -> np.ndarray:
    positions = np.atleast_1d(np.asarray(positions, dtype=float))
    if positions.ndim != 1 or not np.all(np.isfinite(positions)):
        raise InputError(f"positions must be a finite number or 1-D array, got shape {positions.shape}")
    if np.any(np.abs(positions) > RENDER_LIMIT):
        raise InputError(
            f"positions must lie in [-{RENDER_LIMIT}, {RENDER_LIMIT}] (the track is [-1.2, 0.6]; farther out, "
            f"gymnasium's pixel coordinates overflow), got {positions[np.abs(positions) > RENDER_LIMIT][0]}"
        )
    return positions


def _per_image(value, n: int, name: str) -> np.ndarray:
    value = np.asarray(value, dtype=float)
    if value.ndim == 0:
        value = np.full(n, float(value))
    if value.shape != (n,) or not np.all(np.isfinite(value)):
        raise InputError(f"{name} must be a finite number or one value per image ({n}), got shape {value.shape}")
    return value


def contrast(images, factor) -> np.ndarray:
    """PIL's ``ImageEnhance.Contrast(image).enhance(factor)`` on each image (N x H x W in [0, 1]).

    PIL works on 8-bit grey: pixels are rounded to 1/255, moved ``factor`` times away from the
    image's mean grey (rounded to an integer level), clipped and truncated to 8 bits; 0 gives a flat
    grey image, 1 the image. ``factor`` is a number or one per image.
    """
    try:
        from PIL import Image, ImageEnhance
    except ImportError:
        raise MissingDependencyError("contrast needs pillow: pip install 'percver[cases]'") from None
    images = np.asarray(images, dtype=float)
    if images.ndim != 3:
        raise InputError(f"contrast() takes a stack of images (N x H x W), got shape {images.shape}")
    factors = _per_image(factor, len(images), "the contrast factor")
    levels = np.round(np.clip(images, 0.0, 1.0) * 255.0).astype(np.uint8)
    out = np.empty(images.shape)
    for i, (image, f) in enumerate(zip(levels, factors)):
        grey = Image.fromarray(image)  # 2-D uint8: mode "L"
        out[i] = np.asarray(ImageEnhance.Contrast(grey).enhance(float(f)), dtype=float)
    return out / 255.0


def blur(positions, delta_b) -> np.ndarray:
    """The paper's blur of the canonical scene: ``0.5 g(p - d) + g(p) + 0.5 g(p + d)`` rescaled to [0, 1]."""
    return observe(positions, delta_b=delta_b)
