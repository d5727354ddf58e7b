"""Every Flow* benchmark model in ../shared/anchors/flowstar_models parses and runs with its own
settings; the runs that finish are checked against simulation at the horizon."""

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import percver as pv

MODELS = Path(__file__).resolve().parents[1].parent / "shared" / "anchors" / "flowstar_models"


def test_shared_models_are_present():
    assert MODELS.is_dir(), f"{MODELS} is missing: CI has ../shared beside the repo"
    assert len(list(MODELS.glob("*.model"))) >= 20


@pytest.mark.parametrize("path", sorted(MODELS.glob("*.model")), ids=lambda p: p.stem)
def test_model_parses_and_runs(path):
    model = pv.formats.load_flowstar(str(path))
    assert model.variables and set(model.odes) == set(model.variables)
    fp = model.run(on_failure="return")
    assert len(fp.times) > 0 or fp.failure
    # Whatever time was reached, sampled trajectories are inside the final box.
    names = model.variables
    rhs = [pv.parse(model.odes[v]) for v in names]
    box = pv.Box.coerce(model.init, names)
    points = box.sample(20, seed=0)
    final = np.array([fp.final_box()[v] for v in names])
    if fp.time_reached == 0 or not np.all(np.isfinite(final)):
        return

    def f(_t, s):
        return pv.evaluate(rhs, dict(zip(names, s)))[0]

    for p in points:
        sol = solve_ivp(f, (0, fp.time_reached), p, method="DOP853", rtol=1e-11, atol=1e-11)
        end = sol.y[:, -1]
        assert np.all((end >= final[:, 0] - 1e-7) & (end <= final[:, 1] + 1e-7)), (path.stem, end, final)


def test_errors_name_file_and_line(tmp_path):
    bad = tmp_path / "bad.model"
    bad.write_text(
        "continuous reachability\n{\n state var x\n setting\n {\n  fixed steps 0.1\n  time 1\n  fixed orders 4\n  warp drive on\n }\n nonpoly ode\n {\n  x' = -x\n }\n init\n {\n  x in [0, 1]\n }\n}\n"
    )
    with pytest.raises(pv.ParseError, match=r"bad.model, line 9, column 3: unsupported setting 'warp drive on'"):
        pv.formats.load_flowstar(str(bad))
    bad.write_text(bad.read_text().replace("  warp drive on\n", "").replace("x' = -x", "y' = -x"))
    with pytest.raises(pv.ParseError, match="undeclared variable 'y'"):
        pv.formats.load_flowstar(str(bad))
    bad.write_text(bad.read_text().replace("y' = -x", "x' = -x +"))
    with pytest.raises(pv.ParseError, match=r"line 12, column 12: expected an expression, found '}'"):
        pv.formats.load_flowstar(str(bad))
    with pytest.raises(FileNotFoundError):
        pv.formats.load_flowstar(str(tmp_path / "none.model"))
