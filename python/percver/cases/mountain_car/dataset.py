"""The paper's training set D of Mountain Car (Appendix A.3): per position, the canonical image of
:mod:`percver.cases.mountain_car.camera` and contrasted and blurred ones.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from percver.cases.mountain_car.camera import PIXELS, SHAPE, camera, contrast
from percver.cases.mountain_car.dynamics import BLUR_RANGE, CONTRAST_RANGE, P_MAX, P_MIN
from percver.errors import InputError, MissingFileError, ParseError
from percver.validate.effects.camera import motion_blur


@dataclass
class Dataset:
    """The paper's training set D: per position, its canonical image and ``k`` contrasted and ``k`` blurred images.

    Arrays: ``positions`` (n,), ``canonical`` (n, 20, 30), ``delta_c`` and ``delta_b`` (n, k),
    ``contrast`` and ``blur`` (n, k, 20, 30); images float32 in [0, 1].
    """

    positions: np.ndarray
    canonical: np.ndarray
    delta_c: np.ndarray
    contrast: np.ndarray
    delta_b: np.ndarray
    blur: np.ndarray
    meta: dict = field(default_factory=dict)

    FIELDS = ("positions", "canonical", "delta_c", "contrast", "delta_b", "blur")

    def __post_init__(self):
        n = len(self.positions)
        k = self.delta_c.shape[1] if self.delta_c.ndim == 2 else -1
        expected = {
            "positions": (n,), "canonical": (n, *SHAPE), "delta_c": (n, k), "contrast": (n, k, *SHAPE),
            "delta_b": (n, k), "blur": (n, k, *SHAPE),
        }  # fmt: skip
        where = self.meta.get("path", "dataset")
        for name, shape in expected.items():
            value = getattr(self, name)
            if value.shape != shape:
                raise ParseError(
                    f"{where}: field '{name}' has shape {value.shape}, expected {shape} "
                    "(n positions, k noise levels, 20 x 30 images); regenerate it with `percver cases mountain-car data`"
                )
            if not np.all(np.isfinite(value)):
                raise ParseError(f"{where}: field '{name}' holds NaN or inf; regenerate the data set")

    @property
    def n_positions(self) -> int:
        return len(self.positions)

    @property
    def per_position(self) -> int:
        return self.delta_c.shape[1]

    def __len__(self) -> int:
        """Number of examples (canonical, contrasted and blurred images): 82,000 for the paper's D."""
        return self.n_positions * (1 + 2 * self.per_position)

    def noise_pairs(self, kind: str, index=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(canonical images (m, 600), noise parameters (m,), noised images (m, 600)) of ``kind``
        ("contrast" or "blur"), over the positions ``index`` (all by default)."""
        if kind not in ("contrast", "blur"):
            raise InputError(f"noise kind must be 'contrast' or 'blur', got '{kind}'")
        index = np.arange(self.n_positions) if index is None else np.asarray(index)
        deltas = (self.delta_c if kind == "contrast" else self.delta_b)[index]
        noised = getattr(self, kind)[index]
        k = deltas.shape[1]
        clean = np.repeat(self.canonical[index].reshape(len(index), PIXELS), k, axis=0)
        return clean, deltas.reshape(-1), noised.reshape(-1, PIXELS)

    def images(self, index=None) -> tuple[np.ndarray, np.ndarray]:
        """All images of the positions ``index`` (m, 600) with their positions (m,): the estimator's data."""
        index = np.arange(self.n_positions) if index is None else np.asarray(index)
        k = self.per_position
        images = np.concatenate(
            [self.canonical[index].reshape(-1, PIXELS), self.contrast[index].reshape(-1, PIXELS),
             self.blur[index].reshape(-1, PIXELS)]
        )  # fmt: skip
        p = self.positions[index]
        return images, np.concatenate([p, np.repeat(p, k), np.repeat(p, k)])

    def save(self, path) -> Path:
        """Write a compressed ``.npz`` (``meta`` as a JSON string)."""
        import json

        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = {key: value for key, value in self.meta.items() if key != "path"}
        np.savez_compressed(path, **{name: getattr(self, name) for name in self.FIELDS}, meta=json.dumps(meta))
        return path

    @classmethod
    def load(cls, path) -> "Dataset":
        import json

        path = Path(path)
        if not path.is_file():
            raise MissingFileError(f"data set not found: {path}; make it with `percver cases mountain-car data --out {path}`")
        try:
            with np.load(path, allow_pickle=False) as npz:
                missing = [name for name in cls.FIELDS if name not in npz.files]
                if missing:
                    raise ParseError(
                        f"{path}: missing field(s) {missing}; a Mountain Car data set has {list(cls.FIELDS)} "
                        "(make one with `percver cases mountain-car data`)"
                    )
                arrays = {name: np.asarray(npz[name]) for name in cls.FIELDS}
                meta = json.loads(str(npz["meta"])) if "meta" in npz.files else {}
        except ParseError:
            raise
        except (OSError, ValueError, zipfile.BadZipFile):
            # numpy's own message suggests allow_pickle=True, which would run code from the file.
            raise ParseError(
                f"{path}: the file is corrupt or not a Mountain Car data set (make one with `percver cases mountain-car data`)"
            ) from None
        return cls(**arrays, meta={**meta, "path": str(path)})


def _levels(rng, n: int, k: int, bounds, stratified: bool) -> np.ndarray:
    """(n, k) noise levels over ``bounds``: one uniform draw per k-th of the range (stratified), or the
    k evenly spaced levels for every position."""
    lo, hi = bounds
    if not stratified:
        return np.tile(np.linspace(lo, hi, k), (n, 1))
    return lo + (np.arange(k)[None, :] + rng.random((n, k))) * (hi - lo) / k


def generate(
    n_positions: int = 2000,
    per_position: int = 20,
    *,
    seed: int = 0,
    stratified: bool = True,
    progress: bool = True,
) -> Dataset:
    """The paper's training set D: ``n_positions`` evenly spaced positions over [-1.2, 0.6], each with its
    canonical image, ``per_position`` contrasted (delta_c in [0.3, 2]) and as many blurred (delta_b in
    [0, 0.3]) images; 2000 x (1 + 20 + 20) = 82,000 examples by default.

    The paper samples the noise levels "evenly"; by default each position gets one level from each
    of ``per_position`` equal slices of the range (drawn from ``seed``), so that the noise models see
    the whole continuum, not 20 repeated values. ``stratified=False`` uses the same 20 evenly spaced
    levels everywhere.
    """
    if n_positions < 2 or per_position < 1:
        raise InputError(f"need at least 2 positions and 1 noise level per position, got {n_positions} and {per_position}")
    rng = np.random.default_rng(seed)
    positions = np.linspace(P_MIN, P_MAX, n_positions)
    delta_c = _levels(rng, n_positions, per_position, CONTRAST_RANGE, stratified)
    delta_b = _levels(rng, n_positions, per_position, BLUR_RANGE, stratified)
    cam = camera()
    canonical = np.empty((n_positions, *SHAPE), dtype=np.float32)
    contrasted = np.empty((n_positions, per_position, *SHAPE), dtype=np.float32)
    blurred = np.empty((n_positions, per_position, *SHAPE), dtype=np.float32)
    iterator = range(n_positions)
    if progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, desc="Mountain Car data set", unit="position")
    for i in iterator:
        p = np.full(per_position, positions[i])
        image = cam.render(positions[i : i + 1])
        canonical[i] = image[0]
        contrasted[i] = contrast(np.repeat(image, per_position, axis=0), delta_c[i])
        blurred[i] = motion_blur(cam.render(p - delta_b[i]), image, cam.render(p + delta_b[i]))
    meta = {"seed": seed, "n_positions": n_positions, "per_position": per_position, "stratified": stratified}
    return Dataset(positions, canonical, delta_c, contrasted, delta_b, blurred, meta=meta)
