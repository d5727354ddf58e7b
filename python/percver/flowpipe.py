"""ODE reachability: ``pv.flowpipe({x: v, v: ...}, init=..., t_end=...)`` over the Rust engine."""

from __future__ import annotations

import json
from typing import Mapping, Optional, Sequence, Union

import numpy as np

from percver import _core
from percver.errors import BlowUpError, InputError
from percver.expr import ExprLike, as_expr, name_of
from percver.sets import Box, BoxLike


def _hull_in_mode(array: np.ndarray, modes: Sequence[str], names: Sequence[str], mode: Optional[str]) -> dict:
    """Hull of the step boxes ``array`` (steps x variables x [lo, hi]) whose mode is ``mode`` (all if None)."""
    keep = [i for i, m in enumerate(modes) if mode is None or m == mode]
    if not keep:
        raise InputError(f"no run reaches mode '{mode}' (modes reached: {sorted(set(modes))})")
    part = array[keep]
    return {v: (float(part[:, j, 0].min()), float(part[:, j, 1].max())) for j, v in enumerate(names)}


class Flowpipe:
    """The reach set of an ODE: one box per integration step plus the final state's box.

    Every box is a sound enclosure of all trajectories from the initial set over the step's
    time interval ``times[i]``.
    """

    def __init__(self, raw, settings: dict):
        self._raw = raw
        self.names = list(raw.names)
        self.times = np.asarray(raw.times)  # (S, 2)
        self.array = np.asarray(raw.boxes)  # (S, n, 2)
        self.time_reached = raw.time_reached
        self.failure: Optional[str] = raw.failure
        self.orders = list(raw.orders)
        self.stats = dict(raw.stats)
        self.settings = settings

    def final_box(self, bounder: Optional[str] = None, split: Optional[int] = None) -> dict:
        """Box of the state at ``time_reached``: the range of the final Taylor models.

        ``bounder`` trades time for tightness: ``"dominated"`` (default, linear dominated
        bounder), ``"interval"`` (monomial-wise interval evaluation, what Flow* prints),
        ``"subdivision"`` (the initial set cut into ``split`` pieces per variable, each piece
        re-expanded and bounded; ``split=k`` alone selects it) or ``"bernstein"`` (refused
        when the models have too many Bernstein coefficients). All are sound enclosures.
        """
        if bounder is None:
            bounder = "subdivision" if split is not None else "dominated"
        if bounder == "dominated" and split is None:
            bounds = self._raw.final_box
        else:
            if split is not None and (not isinstance(split, int) or split < 1):
                raise InputError(f"split must be a positive number of pieces per variable, got {split!r}")
            bounds = self._raw.final_bound(bounder, 4 if split is None else split)
        return {n: tuple(b) for n, b in zip(self.names, bounds)}

    def final_models(self) -> list:
        """The state at ``time_reached`` as one :class:`FinalModel` per variable: a polynomial
        over the normalised initial set plus an interval remainder."""
        names = self.names
        centre_radius = self._raw.initial_map()
        return [
            FinalModel(name, names, dict((tuple(int(e) for e in exps), c) for exps, c in terms), tuple(rem), centre_radius, self._raw, i)
            for i, (name, (terms, rem)) in enumerate(zip(names, self._raw.final_models()))
        ]

    def final_enclose(self, points: np.ndarray) -> np.ndarray:
        """Rigorous enclosures (N, n, 2) of the states reached at ``time_reached`` from initial
        points (N, n) of the initial box."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        if pts.shape[1] != len(self.names):
            raise InputError(f"points need {len(self.names)} columns ({', '.join(self.names)}), got {pts.shape[1]}")
        return np.asarray(self._raw.final_enclose(pts.tolist()))

    def boxes(self) -> list:
        """Per-step boxes as dicts ``{"t": (t0, t1), name: (lo, hi), ...}``."""
        return [
            {"t": tuple(self.times[i]), **{n: tuple(self.array[i, j]) for j, n in enumerate(self.names)}} for i in range(len(self.times))
        ]

    def hull(self) -> Box:
        """One box containing the whole flowpipe."""
        return Box(
            tuple(self.names), tuple((float(self.array[:, j, 0].min()), float(self.array[:, j, 1].max())) for j in range(len(self.names)))
        )

    def reach_box(self, mode: Optional[str] = None) -> dict:
        """Hull of the step boxes (of those in ``mode``, if given): every state the runs reach
        there, e.g. the outputs of a network's last, zero-dwell mode."""
        return _hull_in_mode(self.array, self.modes, self.names, mode)

    def contains(self, t: np.ndarray, states: np.ndarray, tol: float = 0.0) -> np.ndarray:
        """Whether states (N x n) at times t (N) lie in the box of a step whose closed time interval holds their time.

        The steps tile [0, time_reached]: each starts on the very float where the previous one
        ends, so every time in it is in one step, or in two on a boundary (either box will do).
        """
        t = np.asarray(t, dtype=float).reshape(-1)
        states = np.atleast_2d(np.asarray(states, dtype=float))
        if states.shape != (len(t), len(self.names)):
            raise InputError(
                f"contains needs one state of {len(self.names)} values per time: {len(t)} times, states of shape {states.shape}"
            )
        ok = np.zeros(len(t), dtype=bool)
        if len(self.times) == 0:
            return ok
        first = np.searchsorted(self.times[:, 1], t, side="left")  # the first step ending at or after t
        for step in (first, first + 1):
            s = np.minimum(step, len(self.times) - 1)
            covers = (step < len(self.times)) & (self.times[s, 0] <= t) & (t <= self.times[s, 1])
            box = self.array[s]
            ok |= covers & np.all((states >= box[:, :, 0] - tol) & (states <= box[:, :, 1] + tol), axis=1)
        return ok

    def to_json(self, path: Optional[str] = None) -> str:
        doc = {
            "names": self.names,
            "settings": self.settings,
            "time_reached": self.time_reached,
            "failure": self.failure,
            "final_box": self.final_box(),
            "times": self.times.tolist(),
            "boxes": self.array.tolist(),
            "stats": self.stats,
        }
        text = json.dumps(doc, indent=1)
        if path:
            with open(path, "w") as f:
                f.write(text)
        return text

    def plot(self, x: str, y: str, path: Optional[str] = None, ax=None, samples: Optional[np.ndarray] = None):
        """Draw the step boxes in the (x, y) plane (``y`` may be "t" for a time plot)."""
        import matplotlib

        if ax is None:
            matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.collections import PatchCollection
        from matplotlib.patches import Rectangle

        def column(name):
            if name == "t":
                return self.times
            if name not in self.names:
                raise InputError(f"no variable '{name}' in the flowpipe (have {self.names} and 't')")
            return self.array[:, self.names.index(name), :]

        cx, cy = column(x), column(y)
        own = ax is None
        if own:
            fig, ax = plt.subplots(figsize=(6, 5))
        rects = [Rectangle((a[0], b[0]), a[1] - a[0], b[1] - b[0]) for a, b in zip(cx, cy)]
        ax.add_collection(PatchCollection(rects, facecolor="tab:green", edgecolor="darkgreen", linewidth=0.3, alpha=0.5))
        if samples is not None:
            ax.plot(samples[..., 0].T, samples[..., 1].T, color="tab:red", linewidth=0.5)
        ax.set_xlim(cx[:, 0].min(), cx[:, 1].max())
        ax.set_ylim(cy[:, 0].min(), cy[:, 1].max())
        ax.autoscale_view()
        ax.set_xlabel(x)
        ax.set_ylabel(y)
        ax.set_title(f"flowpipe, {len(self.times)} steps to t = {self.time_reached:g}")
        if own and path:
            fig.tight_layout()
            fig.savefig(path, dpi=120)
            plt.close(fig)
        return ax


class FinalModel:
    """One state variable at the final time: ``x(t_end) in p(z) + remainder`` for every start
    ``x0 = centre + radius * z`` of the initial box (z in [-1, 1]^n; a zero radius marks a
    point-valued variable, whose z is 0).

    ``coefficients`` maps exponent tuples of (z_1, ..., z_n) to float coefficients.
    """

    def __init__(self, name, names, coefficients, remainder, centre_radius, raw, index):
        self.name = name
        self.variables = list(names)
        self.coefficients = coefficients
        self.remainder = remainder
        self.centre_radius = list(centre_radius)
        self._raw = raw
        self._index = index

    def normalise(self, points: np.ndarray) -> np.ndarray:
        """z of initial points (float, approximate: use :meth:`enclose` for rigorous bounds)."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        c = np.array([cr[0] for cr in self.centre_radius])
        r = np.array([cr[1] for cr in self.centre_radius])
        return np.where(r > 0, (pts - c) / np.where(r > 0, r, 1.0), 0.0)

    def polynomial(self, points: np.ndarray) -> np.ndarray:
        """Float value of the polynomial part at initial points (not rigorous)."""
        z = self.normalise(points)
        out = np.zeros(len(z))
        for exps, c in self.coefficients.items():
            out += c * np.prod(z ** np.array(exps), axis=1)
        return out

    def enclose(self, points: np.ndarray) -> np.ndarray:
        """Rigorous (N, 2) bounds on this variable at the final time from initial points (N, n)."""
        pts = np.atleast_2d(np.asarray(points, dtype=float))
        return np.asarray(self._raw.final_enclose(pts.tolist()))[:, self._index, :]

    def __repr__(self):
        return f"FinalModel({self.name}: {len(self.coefficients)} terms, remainder {self.remainder})"


def flowpipe(
    ode: Mapping[Union[str, object], ExprLike],
    init: BoxLike,
    t_end: float,
    *,
    order: Union[int, Sequence[int]] = 6,
    step: Union[float, Sequence[float]] = 0.02,
    adaptive: Optional[Sequence[float]] = None,
    precondition: str = "identity",
    cutoff: float = 1e-10,
    remainder: Union[float, Mapping[str, float]] = 1e-4,
    refinements: int = 30,
    symbolic_queue: int = 100,
    progress: bool = False,
    on_failure: str = "raise",
) -> Flowpipe:
    """Sound flowpipe of ``ode`` ({variable: right-hand side}) from the box ``init``.

    ``step`` is fixed, or give ``adaptive=(min, max)``; ``order`` is an int or (min, max) for
    adaptive orders. ``symbolic_queue`` is the number of past step remainders kept symbolically
    (linear images of boxes, boxed only when read) before the smallest half is boxed into one. If the enclosure blows up, :class:`BlowUpError` says when (its
    ``partial`` attribute holds the sound part computed so far) unless ``on_failure="return"``.
    """
    names = [name_of(k) for k in ode]
    rhs = [as_expr(v) for v in ode.values()]
    box = Box.coerce(init, names)
    if not (isinstance(t_end, (int, float)) and t_end >= 0 and np.isfinite(t_end)):
        raise InputError(f"t_end must be a finite non-negative number, got {t_end!r}")
    step_arg = tuple(float(s) for s in adaptive) if adaptive is not None else float(step)
    if isinstance(step_arg, tuple) and len(step_arg) != 2:
        raise InputError("adaptive must be (min_step, max_step)")
    order_arg = tuple(int(k) for k in order) if isinstance(order, (list, tuple)) else int(order)
    if isinstance(remainder, Mapping):
        rem = [float(remainder[n]) for n in names]
    else:
        rem = [float(remainder)] * len(names)
    if on_failure not in ("raise", "return"):
        raise InputError("on_failure must be 'raise' or 'return'")
    settings = dict(
        t_end=t_end,
        order=order_arg,
        step=step_arg,
        precondition=precondition,
        cutoff=cutoff,
        remainder=rem,
        refinements=refinements,
        symbolic_queue=symbolic_queue,
    )
    bar = None
    callback = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=float(t_end), unit="t", desc="flowpipe", bar_format="{l_bar}{bar}| t={n:.3g}/{total:.3g} [{elapsed}<{remaining}]")

        def callback(t):
            bar.n = t
            bar.refresh()

    try:
        raw = _core.flowpipe(
            names,
            rhs,
            list(box.bounds),
            float(t_end),
            step_arg,
            order_arg,
            cutoff,
            rem,
            precondition,
            refinements,
            symbolic_queue,
            callback,
        )
    finally:
        if bar is not None:
            bar.close()
    result = Flowpipe(raw, settings)
    if result.failure and on_failure == "raise":
        error = BlowUpError(result.failure)
        error.partial = result
        raise error
    return result


class HybridFlowpipe:
    """The reach set of a hybrid automaton up to a time horizon: one box per integration step
    of every mode visit (``modes[i]`` the mode, ``times[i]`` the step's time span, ``array[i]``
    its box), and the boxes of the states at the horizon (``finals``, with their modes).

    The boxes cover the automaton's states and the clock ``time`` (the last column), the time
    since the start, exact for every run: a run at time t is in a step box whose ``time``
    interval holds t. ``jumps`` says how the state crossed the jumps: ``"taylor"`` (Taylor
    models carried through, Flow*'s way) or ``"box"`` (boxed at every jump).
    """

    def __init__(self, raw, mode_names: list, jumps: str):
        self.names = list(raw.names)
        segments = raw.segments()
        n = len(self.names)
        self.modes = [mode_names[m] for m, *_ in segments]
        self.times = np.array([(t0, t1) for _, t0, t1, _ in segments], dtype=float).reshape(-1, 2)
        self.array = np.array([b for *_, b in segments], dtype=float).reshape(-1, n, 2)
        self.finals = [(mode_names[m], {v: tuple(b) for v, b in zip(self.names, box)}) for m, box in raw.finals()]
        self.failure: Optional[str] = raw.failure
        self.aggregations = raw.aggregations
        self.jumps = jumps

    def final_box(self, mode: Optional[str] = None) -> dict:
        """Hull of the boxes at the horizon (of the runs in ``mode``, if given): ``{variable: (lo, hi)}``."""
        boxes = [b for m, b in self.finals if mode is None or m == mode]
        if not boxes:
            raise InputError(f"no run is in mode '{mode}' at the horizon (final modes: {sorted({m for m, _ in self.finals})})")
        return {v: (min(b[v][0] for b in boxes), max(b[v][1] for b in boxes)) for v in self.names}

    def reach_box(self, mode: Optional[str] = None) -> dict:
        """Hull of the step boxes (of those in ``mode``, if given): every state the runs reach
        there, e.g. the outputs of a network's last, zero-dwell mode."""
        return _hull_in_mode(self.array, self.modes, self.names, mode)

    def contains(self, t: np.ndarray, states: np.ndarray, modes: Optional[Sequence[str]] = None, tol: float = 0.0) -> np.ndarray:
        """Whether states (N x n, the automaton's variables without the clock) at times t (N), in
        ``modes`` (N names, if given), lie in a step box of their mode whose clock holds t."""
        t = np.asarray(t, dtype=float).reshape(-1)
        full = np.column_stack([np.atleast_2d(np.asarray(states, dtype=float)), t])
        if full.shape != (len(t), len(self.names)):
            raise InputError(f"contains needs one state of {len(self.names) - 1} values per time, got {full.shape[1] - 1}")
        out = np.zeros(len(t), dtype=bool)
        lo, hi = self.array[None, :, :, 0] - tol, self.array[None, :, :, 1] + tol
        for a in range(0, len(t), 256):  # rows x steps x variables at a time: bounded memory
            part = full[a : a + 256, None, :]
            inside = np.all((part >= lo) & (part <= hi), axis=2)
            if modes is not None:
                inside &= np.asarray(modes)[a : a + 256, None] == np.asarray(self.modes)[None, :]
            out[a : a + 256] = inside.any(axis=1)
        return out


def hybrid_flowpipe(
    plant,
    init: BoxLike,
    t_end: float,
    *,
    order: Union[int, Sequence[int]] = 6,
    step: Union[None, float, Sequence[float]] = None,
    cutoff: float = 1e-10,
    remainder: Union[None, float, Sequence[float]] = None,
    max_jumps: Optional[int] = None,
    max_branches: int = 64,
    jumps: str = "taylor",
) -> HybridFlowpipe:
    """Sound reach set of the :class:`percver.Hybrid` automaton ``plant`` (without inputs) from the
    box ``init`` in its start mode, up to ``t_end``: Flow*'s hybrid reachability. The runs with
    more than ``max_jumps`` jumps (default: the plant's) are not followed, as in Flow*.

    ``step`` is a float (fixed; default the plant's) or (min, max) (adaptive), ``order`` an int or
    (min, max) (adaptive); ``remainder`` one
    estimate for all variables or one per variable. ``jumps="box"`` boxes the state at every jump
    instead of carrying its Taylor models (sound, wider; in a mode of more variables than one
    flowpipe holds, each group of coupled variables then flows from its own box, halved where its
    flowpipe fails or is loose: the fallback where a wide automaton's models fail, whose
    ``failure`` then says so). ``max_branches`` bounds the branches followed at once (beyond,
    states of one jump are aggregated).

    Wide automata run: the models' symbols are the uncertain variables of ``init`` (past 30
    variables, the widest within a budget, the rest intervals), and each mode is integrated by
    groups of the variables its derivatives couple (at most 31 in one group).
    """
    if plant.inputs:
        raise InputError(f"the hybrid plant reads inputs {plant.inputs}: give it a controller (pv.ClosedLoop) or write them as states")
    if jumps not in ("taylor", "box"):
        raise InputError(f"jumps must be 'taylor' (Taylor models through the jumps) or 'box' (boxed at each jump), got {jumps!r}")
    if not (isinstance(t_end, (int, float)) and t_end > 0 and np.isfinite(t_end)):
        raise InputError(f"t_end must be a finite positive number, got {t_end!r}")
    names, modes, jump_args, start, *_ = plant._core([])
    box = Box.coerce(init, names)
    step = plant.step if step is None else step
    step_arg = (float(step[0]), float(step[1])) if isinstance(step, (list, tuple)) else float(step)
    remainder = plant.remainder if remainder is None else remainder
    rem = [float(r) for r in remainder] if isinstance(remainder, (list, tuple)) else [float(remainder)] * len(names)
    raw = _core.hybrid_reach(
        names,
        modes,
        jump_args,
        start,
        list(box.bounds),
        float(t_end),
        step_arg,
        (int(order[0]), int(order[1])) if isinstance(order, (list, tuple)) else int(order),
        float(cutoff),
        rem,
        plant.max_jumps if max_jumps is None else int(max_jumps),
        int(max_branches),
        jumps == "box",
    )
    result = HybridFlowpipe(raw, list(plant.modes), jumps)
    if result.failure and jumps == "taylor":
        # Not retried on its own: boxes are much coarser where the models get through (interval
        # propagation's width on an exported network), and the user should know which they got.
        result.failure += (
            "; jumps='box' boxes the state at every jump and flows each group of coupled variables from its own box, "
            "halved where needed (coarser, but it decides wide automata such as exported networks where the models fail)"
        )
    return result
