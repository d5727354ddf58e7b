"""``percver verify CONFIG.toml`` and ``percver import-verisig``: a Verisig benchmark imported and
verified (Mountain Car and F1/10, at the defaults), a known-unsafe start falsified with a replaying counterexample, a Python plant with a
reward and a journal, a Flow* model, and bad configs refused with one line and exit status 1."""

import json
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest

import percver as pv
from closed_loops import SUITE, check_against_simulation
from percver.cli import main

TESTS = Path(__file__).parent
MC = SUITE / "mountain_car_small"
MODEL, NET = MC / "MC_small_sig_tmp.model", MC / "sig16x16.yml"
VANDERPOL = TESTS.parents[1] / "shared" / "anchors" / "flowstar_models" / "vanderpol.model"


def percver(*args, cwd):
    return subprocess.run([sys.executable, "-m", "percver.cli", *map(str, args)], capture_output=True, text=True, timeout=300, cwd=cwd)


def test_import_verisig_then_verify(tmp_path):
    r = percver("import-verisig", MODEL, "--networks", NET, "-o", "mc.toml", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "discrete plant, states x1, x2" in r.stdout and "percver verify mc.toml" in r.stdout
    config = tomllib.loads((tmp_path / "mc.toml").read_text())
    assert config["init"] == {"x1": [-0.53, -0.5], "x2": [0.0, 0.0]} and config["property"]["steps"] == 150
    assert Path(config["plant"]["model"]) == MODEL.resolve()
    r = percver("verify", "mc.toml", "--no-progress", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "verdict: verified (100.00%" in r.stdout and "intervals" in r.stdout
    doc = json.loads((tmp_path / "mc.result.json").read_text())
    assert doc["verdict"] == "verified" and doc["settings"]["steps"] == 150 and doc["settings"]["within"]
    # Refused: overwriting, and a network count that does not match the model's DNN modes.
    r = percver("import-verisig", MODEL, NET, "-o", "mc.toml", cwd=tmp_path)
    assert r.returncode == 1 and "exists; pass --force" in r.stderr
    r = percver("import-verisig", MODEL, NET, NET, "-o", "two.toml", cwd=tmp_path)
    assert r.returncode == 1 and "2 network(s)" in r.stderr and r.stderr.count("\n") == 1
    assert not (tmp_path / "two.toml").exists()


def test_f1tenth_benchmark_imported_and_verified_at_the_defaults(tmp_path):
    """Verisig 2.0's F1/10 benchmark as a new user runs it: import, then verify with no option.
    The whole set is lost at step 31 as it is; the adaptive default retries it with state symbols
    (its enclosure wrapped)."""
    f1tenth = SUITE / "f1tenth"
    r = percver(
        "import-verisig", f1tenth / "f1tenth_tanh_verisig.model", "--networks", f1tenth / "tanh64x64.yml", "-o", "f1.toml", cwd=tmp_path
    )
    assert r.returncode == 0, r.stderr
    r = percver("verify", "f1.toml", "--no-progress", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "verdict: verified (100.00%" in r.stdout
    doc = json.loads((tmp_path / "f1.result.json").read_text())
    assert doc["verdict"] == "verified" and doc["coverage"] == 1.0
    assert [c["options"].get("state_symbols") for c in doc["cells"]] == [True]


def test_known_unsafe_start_exits_4_with_a_counterexample_that_replays(tmp_path):
    """Mountain Car from x1 = -0.6 with the authors' sig16x16 controller misses the goal in 150 steps."""
    assert main(["import-verisig", str(MODEL), str(NET), "-o", str(tmp_path / "mc.toml")]) == 0
    text = (tmp_path / "mc.toml").read_text().replace("x1 = [-0.53, -0.5]", "x1 = [-0.6, -0.6]")
    (tmp_path / "unsafe.toml").write_text(text)
    out = tmp_path / "unsafe.json"
    assert main(["verify", str(tmp_path / "unsafe.toml"), "--no-progress", "--out", str(out)]) == 4
    res = pv.Result.from_json(out.read_text())
    cex = res.counterexample
    assert res.verdict == "falsified" and cex.step == 150 and "x1" in cex.violated
    problem = pv.load_verisig(str(MODEL), networks=[str(NET)])
    replay = problem.simulate(np.array([[cex.initial[s] for s in problem.states]]), 150)[0]
    np.testing.assert_allclose(np.asarray(cex.trajectory), replay, rtol=1e-9, atol=1e-12)
    assert replay[:, 0].max() <= 0.45


def python_config(tmp_path, journal=True):
    """mc.toml: the Mountain Car loop from a Python file, 4 cells, with a reward in the goal."""
    (tmp_path / "loop.py").write_text(
        "import sys\n"
        f"sys.path.insert(0, {str(TESTS)!r})\n"
        "from closed_loops import mountain_car\n"
        "def make():\n"
        "    return mountain_car()[0]\n"
    )
    (tmp_path / "mc.toml").write_text(
        '[plant]\npython = "loop.py:make"\n'
        "[init]\np = [-0.53, -0.5]\nv = 0\n"
        "[split]\np = 4\n"
        '[property]\nsteps = 150\nwithin = true\ngoal = ["p >= 0.45", "r + 100 > 90"]\nreward = {r = "-0.1 * u^2"}\n'
        + ('[verify]\nrefine = true\njournal = "run.jsonl"\n' if journal else "")
    )


def test_python_plant_with_reward_journal_and_json(tmp_path):
    python_config(tmp_path)
    r = percver("verify", "mc.toml", "--json", "--workers", "1", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["verdict"] == "verified" and doc["states"] == ["p", "v", "r"] and len(doc["cells"]) == 4
    journal = (tmp_path / "run.jsonl").read_text().splitlines()
    assert len(journal) == 1 + 4
    # The rerun takes every cell from the journal: same verdicts, nothing appended.
    r = percver("verify", "mc.toml", "--no-progress", "--out", "again.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "run.jsonl").read_text().splitlines() == journal
    again = json.loads((tmp_path / "again.json").read_text())
    assert [c["box"] for c in again["cells"]] == [c["box"] for c in doc["cells"]]


def test_scheduler_runs_the_cells_on_dask_workers(tmp_path, monkeypatch, capsys):
    from dask.distributed import Client, LocalCluster, get_task_stream

    python_config(tmp_path, journal=False)
    monkeypatch.chdir(tmp_path)
    with (
        LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
        Client(cluster) as client,
        get_task_stream(client) as stream,
    ):
        code = main(["verify", "mc.toml", "--no-progress", "--scheduler", cluster.scheduler_address])
    assert code == 0, capsys.readouterr().err
    assert len(stream.data) >= 1, "no task reached the Dask worker"
    res = pv.Result.from_json((tmp_path / "mc.result.json").read_text())
    assert res.verdict == "verified" and len(res.cells) == 4


def test_flowstar_model_with_a_safety_property(tmp_path):
    (tmp_path / "vdp.toml").write_text(
        f'[plant]\nmodel = "{VANDERPOL}"\nperiod = 0.1\n[property]\nsafe = ["y <= 3", "x >= -2.5"]\n[split]\nx = 2\n'
    )
    out = tmp_path / "vdp.json"
    assert main(["verify", str(tmp_path / "vdp.toml"), "--no-progress", "--out", str(out)]) == 0
    res = pv.Result.from_json(out.read_text())
    assert res.verdict == "verified" and res.settings["steps"] == 70
    from percver.commands.verify import FlowstarProblem

    target = FlowstarProblem(pv.formats.load_flowstar(str(VANDERPOL)), 0.1)
    x, y = pv.variables("x y")
    assert check_against_simulation(target, {"safe": [y <= 3, x >= -2.5]}, res, n=200) > 0


BAD = {
    "not toml": ("[plant\n", "not valid TOML"),
    "unknown section": ("[plantt]\n", "unknown section [plantt]"),
    "unknown key": ('[plant]\nmodle = "x.model"\n', "[plant]: unknown key 'modle'"),
    "wrong type": (f'[plant]\nmodel = "{MODEL}"\nnetworks = ["{NET}"]\n[verify]\norder = "5"\n', "[verify] order: expected int"),
    "no plant": ("[property]\nsteps = 3\n", "give exactly one of python"),
    "missing model": ('[plant]\nmodel = "none.model"\n', "[plant] model: file not found"),
    "missing network": (f'[plant]\nmodel = "{MODEL}"\nnetworks = ["none.yml"]\n', "[plant] networks[0]: file not found"),
    "not FILE:NAME": ('[plant]\npython = "loop.py"\n', "is not FILE.py:NAME"),
    "bad condition": (
        f'[plant]\nmodel = "{MODEL}"\nnetworks = ["{NET}"]\n[property]\ngoal = "x1 = 0.45"\n',
        "[property] goal: 'x1 = 0.45' is not one comparison",
    ),
    "bad expression": (
        f'[plant]\nmodel = "{MODEL}"\nnetworks = ["{NET}"]\n[property]\nreward = {{r = "x1 +"}}\n',
        "[property] reward.r: expected a number",
    ),
    "unknown variable": (
        f'[plant]\nmodel = "{MODEL}"\nnetworks = ["{NET}"]\n[property]\nsafe = "p >= -1.2"\n',
        "uses ['p'], which are not states of the loop (x1, x2)",
    ),
    "bad init": (f'[plant]\nmodel = "{MODEL}"\nnetworks = ["{NET}"]\n[init]\nx1 = [1, 2, 3]\n', "[init] x1: expected [lo, hi]"),
    "bad split": (f'[plant]\nmodel = "{MODEL}"\nnetworks = ["{NET}"]\n[split]\nx1 = "4"\n', "[split] x1: expected a cell count"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_config_is_one_line_and_exit_1(case, tmp_path, capsys):
    text, message = BAD[case]
    (tmp_path / "bad.toml").write_text(text)
    code = main(["verify", str(tmp_path / "bad.toml"), "--no-progress", "--out", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert code == 1 and message in err and err.count("\n") == 1 and err.startswith("percver verify: error:"), err
    assert not (tmp_path / "r.json").exists()


def test_missing_config(tmp_path, capsys):
    assert main(["verify", str(tmp_path / "none.toml")]) == 1
    assert "config file not found" in capsys.readouterr().err


def test_initial_set_outside_a_declared_range_is_a_one_line_warning(tmp_path, capsys):
    (tmp_path / "loop.py").write_text(
        "import percver as pv\n"
        f"net = pv.load_network({str(SUITE / 'mountain_car_small' / 'sig16x16.yml')!r})\n"
        "p, v, u = pv.variables('p v u')\n"
        "loop = pv.ClosedLoop(pv.Discrete({p: p + v, v: v + 0.001 * u}, inputs=[u]),\n"
        "                     [pv.Stage(net, inputs=[p, v], output='u', domain={v: (-0.07, 0.07)})])\n"
    )
    (tmp_path / "c.toml").write_text(
        '[plant]\npython = "loop.py:loop"\n[init]\np = [-0.5, -0.4]\nv = [0, 0.1]\n[property]\nsteps = 2\nsafe = "p >= -2"\n'
    )
    assert main(["verify", str(tmp_path / "c.toml"), "--no-progress", "--out", str(tmp_path / "r.json")]) == 0
    err = capsys.readouterr().err
    assert err.startswith("percver verify: warning: initial v in [0, 0.1] leaves [-0.07, 0.07]") and err.count("\n") == 1


def test_time_limit_reports_what_did_not_run_and_the_rerun_resumes(tmp_path):
    """--time-limit: past it cells are unknown with the limit as their reason (exit 3), the try:
    line names a longer limit, and the rerun without it runs them from the same journal."""
    python_config(tmp_path)
    r = percver("verify", "mc.toml", "--no-progress", "--time-limit", "1e-6", "--out", "limited.json", cwd=tmp_path)
    assert r.returncode == 3, r.stderr
    assert "time_limit=4e-06" in r.stdout and "try:" in r.stdout
    doc = json.loads((tmp_path / "limited.json").read_text())
    assert [c["reason"] for c in doc["cells"]] == ["not run within time_limit=1e-06 s"] * 4
    r = percver("verify", "mc.toml", "--no-progress", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert len((tmp_path / "run.jsonl").read_text().splitlines()) == 1 + 4


def test_every_verify_keyword_is_a_config_key_and_reaches_verify(tmp_path, monkeypatch):
    """The config's [property] and [verify] keys are pv.verify's keywords (but the loop, init and
    split, which have tables of their own); the example that --help prints parses, and each of its
    values reaches pv.verify."""
    import inspect

    from percver.commands.verify import OPTIONS, example

    keywords = set(inspect.signature(pv.verify).parameters) - {"loop", "init", "split"}
    assert set(OPTIONS) == keywords
    python_config(tmp_path, journal=False)
    text = (tmp_path / "mc.toml").read_text().split("[property]")[0] + "\n".join(l.strip() for l in example().splitlines())
    (tmp_path / "all.toml").write_text(text)
    seen = {}
    monkeypatch.setattr(sys.modules["percver.verification"], "verify", lambda loop, **kwargs: seen.update(kwargs) or pv.Result([], {}, []))
    main(["verify", str(tmp_path / "all.toml"), "--out", str(tmp_path / "r.json")])
    assert set(seen) == keywords | {"init", "split"}
    config = tomllib.loads(text)
    assert seen["rebox"] is config["verify"]["rebox"] is False and seen["max_splits"] == config["verify"]["max_splits"]
    assert seen["batch"] == 8 and seen["executor"] == "tcp://host:8786" and seen["progress"] is True


def test_the_config_reference_in_the_docs_is_current(capsys):
    """docs/verify.md carries `percver verify --config-reference` verbatim: a new option of
    pv.verify (OPTIONS) that is not in the docs fails here."""
    assert main(["verify", "--config-reference"]) == 0
    table = capsys.readouterr().out
    docs = (TESTS.parent / "docs" / "verify.md").read_text()
    assert "| `rebox` | [verify] | boolean | `false` |" in table
    assert table in docs, "docs/verify.md is stale: paste the output of `percver verify --config-reference` into it"


def test_a_window_in_a_config(tmp_path, capsys):
    """safe = {conditions = [...], steps = [first, last]}: pv.during from TOML; [first] runs to the horizon."""
    (tmp_path / "rise.py").write_text("import percver as pv\nx = pv.variables('x')\nloop = pv.ClosedLoop(pv.Discrete({x: x + 0.1}))\n")
    base = '[plant]\npython = "rise.py:loop"\n[init]\nx = [0, 0.05]\n[property]\nsteps = 10\n'
    runs = {
        "late": ('safe = {conditions = ["x >= 0.49"], steps = [5, 10]}\n', 0),
        "early": ('safe = [{conditions = ["x >= 0.49", "x <= 2"], steps = [4]}]\n', 4),
        "avoid": ('unsafe = {conditions = ["x >= 0.2", "x <= 0.3"], steps = [4, 10]}\n', 0),
    }
    for name, (prop, code) in runs.items():
        (tmp_path / f"{name}.toml").write_text(base + prop)
        assert main(["verify", str(tmp_path / f"{name}.toml"), "--no-progress", "--out", str(tmp_path / f"{name}.json")]) == code, name
    capsys.readouterr()
    (tmp_path / "bad.toml").write_text(base + 'safe = {conditions = ["x >= 0"], steps = [5, 1]}\n')
    assert main(["verify", str(tmp_path / "bad.toml"), "--no-progress"]) == 1
    assert (
        "[property] safe: during(): the window (5.0, 1.0) must start at 0 or later and not end before it starts" in capsys.readouterr().err
    )
    (tmp_path / "bad.toml").write_text(base + 'safe = {conditions = ["x >= 0"], seconds = [5, 1]}\n')
    assert main(["verify", str(tmp_path / "bad.toml"), "--no-progress"]) == 1
    assert "[property] safe: a window is {conditions" in capsys.readouterr().err


def test_a_splitter_in_a_config(tmp_path, capsys):
    """[verify] splitter = "bisection" or a table with kind and the class's keywords."""
    from percver.commands.verify import Config
    from percver.verification.splitters import Adaptive, Bisection

    python_config(tmp_path, journal=False)
    base = (tmp_path / "mc.toml").read_text()
    (tmp_path / "s.toml").write_text(base + '[verify]\nsplitter = {kind = "adaptive", max_cells = 64, start = 2}\n')
    splitter = Config(str(tmp_path / "s.toml")).verify_kwargs()["splitter"]
    assert isinstance(splitter, Adaptive) and (splitter.max_cells, splitter.start) == (64, 2)
    (tmp_path / "s.toml").write_text(base.replace("[split]\np = 4\n", "") + '[verify]\nsplitter = "bisection"\n')
    assert type(Config(str(tmp_path / "s.toml")).verify_kwargs()["splitter"]) is Bisection
    for spec, message in (
        ('"halving"', "kind must be one of grid, bisection, adaptive, got 'halving'"),
        ('{kind = "adaptive", cells = 3}', "adaptive: "),
    ):
        (tmp_path / "s.toml").write_text(base + f"[verify]\nsplitter = {spec}\n")
        assert main(["verify", str(tmp_path / "s.toml"), "--no-progress"]) == 1
        assert f"[verify] splitter: {message}" in capsys.readouterr().err
