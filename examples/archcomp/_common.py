"""What every ARCH-COMP AINNCS example shares: where the JuliaReach repeatability package lives,
and the command-line run (verify, print the verdict beside the one JuliaReach asserts, replay a
counterexample)."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import percver as pv

# The JuliaReach ARCH-COMP 2024 package (read in place, never copied): ../shared from the repository.
MODELS = Path(__file__).resolve().parents[3] / "shared" / "data" / "archcomp2024" / "models"


def network(model: str, file: str) -> pv.Network:
    """A controller of ``models/<model>/``."""
    return pv.load_network(MODELS / model / file)


def replays(loop: pv.ClosedLoop, counterexample, kwargs: dict) -> bool:
    """Whether a counterexample's run is what the loop does from its initial state (float
    simulation): the recorded trajectory is reproduced to 1e-6 relative, and the state at the
    reported step leaves the benchmark's ``safe`` set or enters its ``unsafe`` one."""
    from percver.properties import Window, as_region

    x0 = np.array([[counterexample.initial[s] for s in loop.states]])
    steps = len(counterexample.trajectory) - 1
    run = loop.simulate(x0, steps)[0] if steps else x0
    same = np.allclose(run, np.asarray(counterexample.trajectory), rtol=1e-6, atol=1e-9)
    state = run[counterexample.step][None]

    def inside(key):
        value = kwargs.get(key)
        value = value.region if isinstance(value, Window) else value
        return None if value is None else bool(as_region(value, key).holds(loop.states, state)[0])

    safe, unsafe = inside("safe"), inside("unsafe")
    return bool(same and (safe is False or unsafe is True))


def main(problem, expected: str, **options) -> pv.Result:
    """``python examples/archcomp/<name>.py``: verify, print the verdict and JuliaReach's."""
    loop, kwargs = problem(**options)
    result = pv.verify(loop, **kwargs)
    print(result.summary())
    print(f"verdict: {result.verdict} (JuliaReach asserts: {expected})")
    if result.counterexample is not None:
        cex = result.counterexample
        print(f"counterexample from {cex.initial}: '{cex.violated}' at step {cex.step}; replays: {replays(loop, cex, kwargs)}")
    return result


if __name__ == "__main__":
    sys.exit("run one of the benchmark files, e.g. python examples/archcomp/tora.py")
