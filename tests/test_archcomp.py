"""The cheapest ARCH-COMP AINNCS examples end to end (examples/archcomp/): the verdict is the one
JuliaReach's repeatability package asserts, and a falsification's counterexample replays in a
float simulation of the loop. The rest run in bench/archcomp.py."""

import sys
from pathlib import Path

import pytest

import percver as pv

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "archcomp"
sys.path.insert(0, str(EXAMPLES))

from _common import MODELS, replays

pytestmark = pytest.mark.skipif(not MODELS.is_dir(), reason="the ARCH-COMP package is not in ../shared/data/archcomp2024")


@pytest.mark.parametrize(
    "name, variant",
    [
        ("inverted_pendulum", ""),
        ("acc", "relu"),
        ("tora", "relutanh"),
        ("inverted_two_link_pendulum", "more_robust"),
        ("airplane", ""),
        ("vertical_cas", "-25.5"),
    ],
)
def test_verdict_is_juliareachs(name, variant):
    bench = __import__(name)
    loop, kwargs = bench.problem(variant)
    result = pv.verify(loop, progress=False, **kwargs)
    assert result.verdict == bench.VARIANTS[variant], [c.reason for c in result.cells if c.verdict != "verified"][:3]
    if result.verdict == "falsified":
        assert replays(loop, result.counterexample, kwargs)
