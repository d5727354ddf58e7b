"""Is a saved figure drawn? Every axes must show data: pixels inside its frame that differ clearly
from its background (text and spines are outside the frame, light grid lines stay under the
threshold). A tube of 5e-5-wide bands drawn with no edge passes every other check and shows nothing."""

from pathlib import Path

import numpy as np

# Per axes: pixels that must differ from the background by more than INK (0-1 scale, any channel).
MIN_PIXELS = 30
INK = 0.35


def blank_axes(fig, png) -> list:
    """Titles (or positions) of the axes of ``fig`` that show nothing in the saved ``png``."""
    import matplotlib.colors
    import matplotlib.image

    image = matplotlib.image.imread(str(png))[..., :3].astype(float)
    if image.max() > 1.0:
        image /= 255.0
    height, width = image.shape[:2]
    blank = []
    for k, ax in enumerate(fig.axes):
        if not ax.get_visible() or not ax.axison:
            continue
        box = ax.get_position()
        x0, x1 = int(box.x0 * width) + 3, int(box.x1 * width) - 3
        y0, y1 = int((1 - box.y1) * height) + 3, int((1 - box.y0) * height) - 3
        inner = image[y0:y1, x0:x1]
        face = np.asarray(matplotlib.colors.to_rgb(ax.get_facecolor()))
        if inner.size == 0 or (np.abs(inner - face).max(axis=-1) > INK).sum() < MIN_PIXELS:
            blank.append(ax.get_title() or f"axes {k}")
    return blank


def is_png_path(target) -> bool:
    return isinstance(target, (str, Path)) and str(target).lower().endswith(".png")
