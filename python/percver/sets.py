"""Boxes: named intervals, the initial sets and reach-set summaries of percver."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator, Mapping, Sequence, Union

import numpy as np

from percver.errors import InputError

BoxLike = Union["Box", Mapping[str, Sequence[float]], Sequence[Sequence[float]]]


@dataclass(frozen=True)
class Box:
    """An axis-aligned box with a name per dimension; bounds are checked on creation.
    ``Box({"x": (0, 1), "v": (-1, 1)})`` is the same as ``Box(("x", "v"), ((0, 1), (-1, 1)))``."""

    names: tuple
    bounds: tuple = None

    def __post_init__(self):
        if isinstance(self.names, Mapping) and self.bounds is None:
            items = [(str(k), _pair(k, v)) for k, v in self.names.items()]
            object.__setattr__(self, "names", tuple(k for k, _ in items))
            object.__setattr__(self, "bounds", tuple(b for _, b in items))
        if self.bounds is None:
            raise InputError("Box needs {name: (lo, hi)} or names and bounds, e.g. Box({'x': (0, 1)})")
        if len(self.names) != len(self.bounds):
            raise InputError(f"box has {len(self.names)} names but {len(self.bounds)} intervals")
        if len(set(self.names)) != len(self.names):
            raise InputError(f"box names must be unique, got {list(self.names)}")
        for name, (lo, hi) in zip(self.names, self.bounds):
            if math.isnan(lo) or math.isnan(hi):
                raise InputError(f"bound of '{name}' is NaN: [{lo}, {hi}]")
            if lo > hi:
                raise InputError(f"empty interval for '{name}': lower bound {lo} is above upper bound {hi}")
            if math.isinf(lo) or math.isinf(hi):
                raise InputError(f"interval of '{name}' must be finite, got [{lo}, {hi}]")

    @classmethod
    def coerce(cls, value: BoxLike, names: Sequence[str] | None = None) -> "Box":
        """From a Box, a {name: (lo, hi)} mapping, or a list of (lo, hi) with ``names``."""
        if isinstance(value, Box):
            box = value
        elif isinstance(value, Mapping):
            box = cls(value)
        else:
            pairs = [_pair(i, v) for i, v in enumerate(value)]
            names = list(names) if names is not None else [f"x{i}" for i in range(len(pairs))]
            box = cls(tuple(names), tuple(pairs))
        if names is not None:
            missing = [n for n in names if n not in box.names]
            extra = [n for n in box.names if n not in names]
            if missing or extra:
                raise InputError(f"box variables {list(box.names)} do not match {list(names)}: missing {missing}, unknown {extra}")
            box = box.reorder(names)
        return box

    def reorder(self, names: Sequence[str]) -> "Box":
        d = dict(zip(self.names, self.bounds))
        return Box(tuple(names), tuple(d[n] for n in names))

    def __getitem__(self, name: str):
        return dict(zip(self.names, self.bounds))[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self.names)

    def to_dict(self) -> dict:
        return {n: tuple(b) for n, b in zip(self.names, self.bounds)}

    @property
    def lo(self) -> np.ndarray:
        return np.array([b[0] for b in self.bounds])

    @property
    def hi(self) -> np.ndarray:
        return np.array([b[1] for b in self.bounds])

    @property
    def widths(self) -> np.ndarray:
        return self.hi - self.lo

    def contains(self, points: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """Row-wise membership of points (N x n, columns in ``names`` order)."""
        p = np.atleast_2d(points)
        return np.all((p >= self.lo - tol) & (p <= self.hi + tol), axis=1)

    def sample(self, n: int, seed: int = 0) -> np.ndarray:
        rng = np.random.default_rng(seed)
        return self.lo + (self.hi - self.lo) * rng.random((n, len(self.names)))

    def split(self, parts: Mapping[str, Union[int, float]]) -> list["Box"]:
        """Grid split: an int is a count of cells, a float a maximal cell width."""
        axes = []
        for name, (lo, hi) in zip(self.names, self.bounds):
            spec = parts.get(name, 1)
            if isinstance(spec, bool) or not isinstance(spec, (int, float, np.integer, np.floating)):
                raise InputError(f"split of '{name}' must be a cell count (int) or a cell width (float), got {spec!r}")
            if isinstance(spec, (float, np.floating)):
                if not spec > 0:
                    raise InputError(f"split width for '{name}' must be positive, got {spec}")
                count = max(1, math.ceil((hi - lo) / spec - 1e-9))
            else:
                count = int(spec)
                if count < 1:
                    raise InputError(f"split count for '{name}' must be at least 1, got {spec}")
            edges = np.linspace(lo, hi, count + 1)
            edges[0], edges[-1] = lo, hi
            axes.append([(float(edges[i]), float(edges[i + 1])) for i in range(count)])
        cells = [()]
        for axis in axes:
            cells = [c + (b,) for c in cells for b in axis]
        return [Box(self.names, c) for c in cells]

    def __repr__(self) -> str:
        inner = ", ".join(f"{n}: [{lo:.6g}, {hi:.6g}]" for n, (lo, hi) in zip(self.names, self.bounds))
        return f"Box({inner})"


def _pair(key, value) -> tuple:
    try:
        lo, hi = value
        return (float(lo), float(hi))
    except (TypeError, ValueError):
        try:
            v = float(value)
            return (v, v)
        except (TypeError, ValueError):
            raise InputError(f"interval for '{key}' must be (lo, hi) or a number, got {value!r}") from None
