"""``percver demo``: the main job on an embedded default.

Until the Mountain Car case study lands, the demo is the Van der Pol benchmark of Flow*:
a sound flowpipe from the box x in [1.25, 1.55], y in [2.28, 2.32] over 7 time units,
checked against simulated trajectories and drawn to a PNG.
"""

import json

import numpy as np

VDP_INIT = {"x": (1.25, 1.55), "y": (2.28, 2.32)}
VDP_T_END = 7.0


def register(sub) -> None:
    parser = sub.add_parser("demo", help="compute and plot a Van der Pol flowpipe (the embedded default job)")
    parser.add_argument("--out", default="percver-demo.png", help="PNG file to write (default: %(default)s)")
    parser.add_argument("--t-end", type=float, default=VDP_T_END, help="time horizon (default: %(default)s)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.set_defaults(func=run)


def _simulate(points: np.ndarray, t_end: float) -> np.ndarray:
    from scipy.integrate import solve_ivp

    def rhs(_t, s):
        x, y = s
        return [y, (1 - x * x) * y - x]

    ts = np.linspace(0.0, t_end, 400)
    return np.stack([solve_ivp(rhs, (0, t_end), p, t_eval=ts, rtol=1e-10, atol=1e-10).y.T for p in points])


def run(args) -> int:
    import percver as pv

    x, y = pv.variables("x y")
    fp = pv.flowpipe(
        {x: y, y: (1 - x**2) * y - x}, init=VDP_INIT, t_end=args.t_end,
        order=6, step=0.02, progress=not args.no_progress,
    )
    box = pv.Box.coerce(VDP_INIT, ["x", "y"])
    samples = _simulate(box.sample(20, seed=1), args.t_end)
    fp.plot("x", "y", path=args.out, samples=samples)
    final = fp.final_box()
    if args.json:
        print(json.dumps({"final_box": final, "steps": len(fp.times), "seconds": fp.stats["seconds"], "plot": args.out}))
    else:
        print(f"Van der Pol flowpipe: {len(fp.times)} steps to t = {fp.time_reached:g} in {fp.stats['seconds']:.2f} s")
        for name, (lo, hi) in final.items():
            print(f"  {name} in [{lo:.6f}, {hi:.6f}]  (width {hi - lo:.3e})")
        print(f"plot: {args.out}")
    return 0
