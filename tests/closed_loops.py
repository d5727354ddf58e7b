"""The closed loops of the test suite in one catalogue, and the sampling oracle that checks any
verification result against simulation.

``CASES`` maps a name to a function returning ``(target, kwargs)``: ``pv.verify(target, **kwargs)``
is one verification problem (a ``pv.ClosedLoop`` or a loaded Verisig problem). The oracle
(:func:`check_against_simulation`) samples trajectories from every cell and asserts that they lie
in the cell's per-step reach boxes, and that no verified cell holds a sampled violation.
"""

from pathlib import Path

import warnings

import numpy as np

import percver as pv
from percver.properties import Region, Window

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
NETWORKS = DATA / "mountain_car" / "networks"
CONTROLLER = NETWORKS / "ControllerSigmoid16x16.yml"
SUITE = DATA / "verisig2_suite"


def _data(path: Path) -> str:
    assert path.exists(), f"{path} missing: CI has ../shared beside the repo"
    return str(path)


def _mountain_car_plant(p, v, u, *extra):
    """Mountain Car's discrete dynamics with the -1.2 wall; ``extra`` states stay constant (noise)."""
    v_next = pv.clip(v + 0.0015 * u - 0.0025 * pv.cos(3 * p), -0.07, 0.07)
    p_next = p + v_next
    update = {p: pv.where(p_next <= -1.2, -1.2, p_next), v: pv.where(p_next <= -1.2, 0.0, v_next)}
    return pv.Discrete({**update, **{d: d for d in extra}}, inputs=[u])


def mountain_car():
    """State-based Mountain Car with the authors' sig16x16 controller: (loop, p, v, u)."""
    p, v, u = pv.variables("p v u")
    loop = pv.ClosedLoop(_mountain_car_plant(p, v, u), [pv.Stage(pv.load_network(_data(CONTROLLER)), inputs=[p, v], output="u")])
    return loop, p, v, u


def mountain_car_images():
    """Image-based Mountain Car (paper, Appendix A): generator -> contraster (delta) -> estimator -> controller."""
    p, v, d, u = pv.variables("p v delta u")
    net = {
        k: pv.load_network(_data(NETWORKS / f))
        for k, f in {
            "gen": "Generator2x50_100_Decay1TestLoss1.035e-06.yml",
            "con": "Contraster1x50_Decay5TestLoss47.74.yml",
            "est": "CompositeRegressor3x20_20_20_Decay0.001TestLoss5.15e-06Composite.yml",
            "ctl": CONTROLLER.name,
        }.items()
    }
    return pv.ClosedLoop(
        _mountain_car_plant(p, v, u, d),
        [
            pv.Stage(net["gen"], inputs=[p], output="image"),
            pv.Stage(net["con"], inputs=["image", d], output="noisy"),
            pv.Stage(net["est"], inputs=["noisy"], output="p_hat", scale=0.9, offset=-0.3),
            pv.Stage(net["ctl"], inputs=["p_hat", v], output="u"),
        ],
    )


def continuous_tanh():
    """x' = v, v' = u - 0.1 v with u from a small tanh network held over each 0.1 s period."""
    from percver.networks import Layer, Network

    x, v, u = pv.variables("x v u")
    net = Network(
        [
            Layer(np.array([[-0.8, -1.2], [0.3, -0.5]]), np.array([0.0, 0.1]), "tanh"),
            Layer(np.array([[1.0, 0.5]]), np.array([0.0]), "identity"),
        ]
    )
    plant = pv.Continuous({x: v, v: u - 0.1 * v}, inputs=[u], period=0.1, step=0.02)
    return pv.ClosedLoop(plant, [pv.Stage(net, inputs=[x, v], output="u")]), x, v, u


def expression_sensor():
    """Mountain Car seen through an expression sensor with a vector output and a scale/offset map."""
    p, v, u = pv.variables("p v u")
    sensor = pv.Stage([p + 0.01 * pv.sin(5 * p), 10 * v], inputs=[p, v], output="obs", scale=[1.0, 0.1], offset=0.0)
    controller = pv.Stage(pv.load_network(_data(CONTROLLER)), inputs=["obs"], output="u")
    return pv.ClosedLoop(_mountain_car_plant(p, v, u), [sensor, controller]), p


def verisig(name: str, stem: str, network: str):
    return pv.load_verisig(_data(SUITE / name / f"{stem}_verisig.model"), networks=[_data(SUITE / name / network)])


def _cases():
    def mc_goal():
        loop, p, v, u = mountain_car()
        return loop, dict(init={"p": (-0.53, -0.50), "v": (0, 0)}, steps=150, goal=p >= 0.45, within=True, split={"p": 3})

    def mc_reward():
        loop, p, v, u = mountain_car()
        r = pv.variables("r")
        return loop, dict(
            init={"p": (-0.53, -0.50), "v": (0, 0)},
            steps=150,
            reward={"r": -0.1 * u**2},
            goal=[p >= 0.45, r + 100 > 90],
            within=True,
            split={"p": 2},
        )

    def mc_safety():
        loop, p, v, u = mountain_car()
        return loop, dict(init={"p": (-0.5, -0.49), "v": (0, 0)}, steps=40, safe=[v >= -0.07, v <= 0.07], unsafe=p <= -1.3)

    def mc_verisig_method():
        loop, p, v, u = mountain_car()
        return loop, dict(init={"p": (-0.52, -0.51), "v": (0, 0)}, steps=5, safe=p >= -1.2, method="verisig")

    def mc_refined():
        loop, p, v, u = mountain_car()
        # The runs come within 4e-5 of this bound (p >= -1.00781 at step 44); at order 1 the wide cells
        # stay undecided without in-cell splits (max_splits=0), refinement verifies some halves and leaves unknown ones with partial boxes.
        return loop, dict(
            init={"p": (-0.53, -0.50), "v": (0, 0)},
            steps=60,
            safe=p >= -1.00784,
            order=1,
            refine=True,
            min_width={"p": 0.005},
            max_splits=0,
        )

    def mc_split():
        loop, p, v, u = mountain_car()
        # The same cell with in-cell splits: parts are split mid-run and continued (boxes are hulls over parts).
        return loop, dict(init={"p": (-0.53, -0.50), "v": (0, 0)}, steps=60, safe=p >= -1.00784, order=1)

    def mc_images():
        p = pv.variables("p")
        return mountain_car_images(), dict(
            init={"p": (-0.5, -0.49975), "v": (0, 0), "delta": (0.3, 0.6)}, steps=12, safe=p >= -1.2, split={"delta": 2}
        )

    def mc_expression_sensor():
        loop, p = expression_sensor()
        return loop, dict(init={"p": (-0.52, -0.5), "v": (0, 0)}, steps=60, safe=p >= -1.2, split={"p": 2})

    def continuous():
        loop, x, v, u = continuous_tanh()
        return loop, dict(init={"x": (0.9, 1.1), "v": (-0.1, 0.1)}, steps=30, safe=[x <= 1.5, x >= -1.5])

    def continuous_reward():
        loop, x, v, u = continuous_tanh()
        cost = pv.variables("cost")
        return loop, dict(init={"x": (0.9, 1.1), "v": (-0.1, 0.1)}, steps=20, reward={"cost": x**2 + 0.1 * u**2}, safe=cost <= 40)

    cases = {
        f.__name__: f
        for f in (
            mc_goal,
            mc_reward,
            mc_safety,
            mc_verisig_method,
            mc_refined,
            mc_split,
            mc_images,
            mc_expression_sensor,
            continuous,
            continuous_reward,
        )
    }
    for name, stem, network in (
        ("mountain_car_small", "MC_small_sig", "sig16x16.yml"),
        ("ex1_tanh", "ex1_tanh", "tanh20x20.yml"),
        ("ex2_sig", "ex2_sig", "sig20x20.yml"),
        ("ex3_tanh", "ex3_tanh", "tanh20x20.yml"),
    ):
        cases[f"verisig_{name}"] = lambda a=(name, stem, network): (verisig(*a), {})

    def verisig_f1tenth_reboxed():
        # Verisig 2.0's F1/10 model: its LiDAR remainders feed back through the loop, so parts restart from their boxes.
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the file's stray brace, recorded in problem.notes
            problem = pv.load_verisig(
                _data(SUITE / "f1tenth" / "f1tenth_tanh_verisig.model"), networks=[_data(SUITE / "f1tenth" / "tanh64x64.yml")]
            )
        return problem, dict(rebox=True)

    cases["verisig_f1tenth_reboxed"] = verisig_f1tenth_reboxed
    return cases


CASES = _cases()


def verified_loop(target, kwargs) -> pv.ClosedLoop:
    """The loop ``pv.verify(target, **kwargs)`` runs: a problem's loop, with the accumulators added."""
    loop = target if isinstance(target, pv.ClosedLoop) else target.loop
    return loop.with_accumulators(kwargs["reward"]) if kwargs.get("reward") else loop


def _property(target, kwargs):
    """(safe, goal, within) of the call, the loaded problem's if none given: safe and goal as
    predicates on (points, step), judged leaf by leaf here (not by percver's own combination)."""
    if not isinstance(target, pv.ClosedLoop) and not {"safe", "unsafe", "goal"} & set(kwargs):
        d = target.defaults
        kwargs = {**kwargs, "safe": d["safe"], "goal": d["goal"], "within": d["within"]}
    listed = lambda c: [] if c is None else list(c) if isinstance(c, (list, tuple)) else [c]  # noqa: E731
    safe = [_during(c) for c in listed(kwargs.get("safe"))]
    unsafe = listed(kwargs.get("unsafe"))
    if len(unsafe) > 1:  # a list to avoid is one set, the intersection of its members
        unsafe = [pv.all_of(unsafe)]
    safe += [(lambda names, x, t, m=_during(u): ~m(names, x, t) if _active(u, t) else np.ones(len(x), bool)) for u in unsafe]
    goal = [_during(c) for c in listed(kwargs.get("goal"))]
    return safe, goal, kwargs.get("within", False)


def _active(item, t) -> bool:
    """Whether a windowed requirement (pv.during with steps=) applies at step t."""
    return not isinstance(item, Window) or item.steps[0] <= t <= (item.steps[1] if item.steps[1] is not None else t)


def _during(item):
    """A predicate (names, points, step) -> rows inside ``item`` (always inside outside its window)."""
    if isinstance(item, Window):
        assert item.steps is not None, "the oracle handles windows given in steps"
        inner = _during(item.region)
        return lambda names, x, t: inner(names, x, t) if _active(item, t) else np.ones(len(x), bool)
    return lambda names, x, t: _inside(item, names, x)


def _inside(item, names, x) -> np.ndarray:
    """Row-wise membership in a condition, box or region, member by member."""
    if isinstance(item, Region):
        parts = [_inside(p, names, x) for p in item.parts]
        return np.logical_and.reduce(parts) if item.kind == "all" else np.logical_or.reduce(parts)
    if isinstance(item, (pv.Box, dict)):
        box = item if isinstance(item, pv.Box) else pv.Box(item)
        cols = [x[:, list(names).index(n)] for n in box.names]
        return np.logical_and.reduce([(c >= lo) & (c <= hi) for c, (lo, hi) in zip(cols, box.bounds)])
    m = pv.evaluate(item.margin(), {n: x[:, j] for j, n in enumerate(names)})
    return {"<": m < 0, "<=": m <= 0, ">": m > 0, ">=": m >= 0}[item.op]


def _holds(conditions, names, points, t) -> np.ndarray:
    """Row-wise: all predicates hold at the points (N x n) at step t."""
    return np.logical_and.reduce([c(names, points, t) for c in conditions] + [np.ones(len(points), bool)])


def check_against_simulation(target, kwargs, result, n=1000, seed=1):
    """Sampling oracle: ``n`` trajectories from random states of each cell lie inside the cell's
    reach box at every step it reports (continuous plants: up to 1e-9, the float integrator's
    error), and satisfy the property when the cell is verified. Returns the number of boxes checked."""
    loop = verified_loop(target, kwargs)
    assert result.states == loop.states
    safe, goal, within = _property(target, kwargs)
    tol = 1e-9 if isinstance(loop.plant, pv.Continuous) else 0.0
    checked = 0
    for k, cell in enumerate(result.cells):
        x0 = pv.Box.coerce(cell.box, loop.states).sample(n, seed=seed + k)
        steps = result.settings["steps"]
        traj = loop.simulate(x0, steps)
        if cell.boxes:
            boxes = np.asarray(cell.boxes)
            part = traj[:, : len(boxes)]
            outside = (part < boxes[None, :, :, 0] - tol) | (part > boxes[None, :, :, 1] + tol)
            if outside.any():
                i, t, j = np.argwhere(outside)[0]
                raise AssertionError(
                    f"cell {cell.box}: {np.count_nonzero(outside)} simulated values outside the reach boxes, first "
                    f"{loop.states[j]} = {part[i, t, j]!r} at step {t} outside {tuple(boxes[t, j])}"
                )
            checked += boxes.size // 2
        if cell.verdict == "verified":
            reached = np.zeros(n, dtype=bool)
            for t in range(steps + 1):
                at_goal = _holds(goal, loop.states, traj[:, t], t) if goal and (within or t == steps) else np.zeros(n, dtype=bool)
                # The engine stops checking safety at the step the goal holds on the whole set.
                unsafe = ~reached & ~_holds(safe, loop.states, traj[:, t], t)
                assert not unsafe.any(), f"verified cell {cell.box}: a sampled run is unsafe at step {t}"
                reached |= at_goal
            assert not goal or reached.all(), f"verified cell {cell.box}: a sampled run misses the goal"
    return checked
