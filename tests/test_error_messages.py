"""Bad input a new user meets first: each error names the file and the field or line, gives the fix,
and is a percver.PercverError (issue 29's list)."""

import subprocess
import sys
import zipfile

import numpy as np
import pytest

import percver as pv
from percver import _core

FLOWSTAR = """continuous reachability
{
 state var x, y
 setting
 {
  fixed steps 0.1
  time 1
  fixed orders 4
 }
 nonpoly ode
 {
  x' = y
  y' = -x + yy
 }
 init
 {
  x in [0, 1]
  y in [0, 1]
 }
}
"""


def cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "percver.cli", *args], capture_output=True, text=True, timeout=300, cwd=cwd)


def test_flowstar_ode_typo_names_file_line_and_equation(tmp_path):
    model = tmp_path / "osc.model"
    model.write_text(FLOWSTAR)
    with pytest.raises(pv.ParseError) as caught:
        pv.formats.load_flowstar(str(model))
    message = str(caught.value)
    assert "osc.model, line 13" in message
    assert "y' = -x + yy" in message and "'yy'" in message and "state var: x, y" in message


def test_flowstar_ode_typo_in_a_verify_config(tmp_path):
    (tmp_path / "osc.model").write_text(FLOWSTAR)
    (tmp_path / "run.toml").write_text('[plant]\nmodel = "osc.model"\n[property]\nsafe = "x <= 10"\n')
    run = cli("verify", "run.toml", "--no-progress", cwd=tmp_path)
    assert run.returncode == 1
    assert "osc.model, line 13" in run.stderr and "'yy'" in run.stderr


def test_missing_flowstar_file_is_a_percver_error_and_a_file_not_found_error(tmp_path):
    with pytest.raises(pv.PercverError) as caught:
        pv.formats.load_flowstar(str(tmp_path / "nope.model"))
    assert isinstance(caught.value, FileNotFoundError)
    assert "nope.model" in str(caught.value)


@pytest.mark.parametrize(
    "bounds, words",
    [
        ("[0.5, 0.1]", "lower bound 0.5 is above upper bound 0.1; write [0.1, 0.5]"),
        ("[nan, 0.1]", "the bounds must be finite"),
        ("nan", "the bounds must be finite"),
    ],
)
def test_bad_init_bounds_name_the_config_and_the_field(tmp_path, bounds, words):
    (tmp_path / "osc.model").write_text(FLOWSTAR.replace(" + yy", ""))
    config = tmp_path / "run.toml"
    config.write_text(f'[plant]\nmodel = "osc.model"\n[init]\nx = {bounds}\ny = [0, 1]\n[property]\nsafe = "x <= 10"\n')
    run = cli("verify", str(config), "--no-progress", cwd=tmp_path)
    assert run.returncode == 1, run.stdout
    assert f"{config}: [init] x: {words}" in run.stderr


def test_config_without_property_names_the_config_keys(tmp_path):
    (tmp_path / "osc.model").write_text(FLOWSTAR.replace(" + yy", ""))
    (tmp_path / "run.toml").write_text('[plant]\nmodel = "osc.model"\n')
    run = cli("verify", "run.toml", "--no-progress", cwd=tmp_path)
    assert run.returncode == 1
    assert "run.toml: [property]: nothing to verify" in run.stderr
    assert 'goal = "' in run.stderr and "safe = [" in run.stderr
    assert "safe=..." not in run.stderr  # the Python keywords are not what a config writes


@pytest.mark.parametrize("content", [b"not an npz at all", b"PK\x03\x04 truncated zip"])
def test_corrupt_measurement_file_says_so_and_never_suggests_pickle(tmp_path, content):
    path = tmp_path / "runs.npz"
    path.write_bytes(content)
    with pytest.raises(pv.MeasurementError) as caught:
        pv.Measurements.load(path)
    message = str(caught.value)
    assert "runs.npz" in message and "corrupt or not a percver measurement file" in message
    assert "pickle" not in message


def test_truncated_measurement_file_says_corrupt(tmp_path):
    good = tmp_path / "good.npz"
    np.savez(good, states=np.zeros((3, 2)), measurements=np.zeros((3, 1)))
    bad = tmp_path / "bad.npz"
    bad.write_bytes(good.read_bytes()[:60])
    assert not zipfile.is_zipfile(bad)
    with pytest.raises(pv.MeasurementError, match="corrupt or not a percver measurement file"):
        pv.Measurements.load(bad)


def _without_shared(tmp_path, *args):
    import os

    empty = tmp_path / "empty"
    empty.mkdir(exist_ok=True)
    env = {k: v for k, v in os.environ.items() if k not in ("PERCVER_SHARED", "PERCVER_F1TENTH_DATA")}
    return subprocess.run(
        [sys.executable, "-m", "percver.cli", *args],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
        env={**env, "PERCVER_SHARED": str(empty)},
    )


def test_commands_that_need_the_shared_data_say_where_it_goes(tmp_path):
    """Without the authors' data, each command says what it is, where it sits and how to point to it."""
    mc = _without_shared(tmp_path, "cases", "mountain-car", "verify", "--networks", "paper", "--p0", "-0.5", "-0.4995")
    assert mc.returncode == 1
    assert "../shared/data" in mc.stderr and "PERCVER_SHARED" in mc.stderr and "--networks ours" in mc.stderr
    f1 = _without_shared(tmp_path, "cases", "f1tenth", "verify", "--y1", "0.65", "0.6501", "--no-progress")
    assert f1.returncode == 1
    assert "PERCVER_SHARED" in f1.stderr and "f1tenth" in f1.stderr


def test_mountain_car_commands_share_their_network_default():
    from percver.cli import build_parser

    parser = build_parser()
    verify = parser.parse_args(["cases", "mountain-car", "verify"])
    evaluate = parser.parse_args(["cases", "mountain-car", "evaluate"])
    assert verify.networks == evaluate.networks == "ours"


@pytest.mark.parametrize("value, shown", [(-1.0, "-1"), (float("nan"), "NaN"), (float("inf"), "inf")])
def test_a_bad_max_redone_names_the_setting_and_the_value(value, shown):
    """The engine's bound on steps computed again by splits that restart: a negative or
    non-finite one is refused by name, not run as a bound no split can meet."""
    with pytest.raises(pv.InputError, match=f"max_redone .* must be a finite non-negative number, got {shown}$"):
        _core.CellSettings(max_redone=value)
    assert _core.CellSettings(max_redone=0.0).max_redone == 0.0
