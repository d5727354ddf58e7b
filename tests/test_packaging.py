"""What a user sees of the package itself: the light core without the extras, the version, the
typing files, the CLI's exit codes and its help text."""

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

import percver
import percver._core

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = Path(percver.__file__).resolve().parent
# Modules of the extras ([train], [cases], [dist], [plot], [data]); the core must not need them.
EXTRAS = ("torch", "matplotlib", "gymnasium", "dask", "distributed", "PIL", "pyarrow")

# Runs the CLI with every extra's module made unimportable (None in sys.modules makes `import`
# raise ModuleNotFoundError), as in a `pip install percver` without extras.
WITHOUT_EXTRAS = f"""
import sys
for name in {EXTRAS!r}:
    sys.modules[name] = None
from percver.cli import main
code = main(sys.argv[1:])
loaded = sorted(name for name in {EXTRAS!r} if sys.modules.get(name) is not None)
print("extras loaded:", loaded)
sys.exit(code)
"""


def without_extras(*args, cwd=None):
    return subprocess.run([sys.executable, "-c", WITHOUT_EXTRAS, *args], capture_output=True, text=True, timeout=600, cwd=cwd)


def test_import_loads_no_extra():
    run = subprocess.run(
        [sys.executable, "-c", f"import sys, percver; print([m for m in {EXTRAS!r} if m in sys.modules])"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "[]"


def test_help_of_every_command_without_extras():
    for command in ([], ["demo"], ["verify"], ["validate"], ["cases"], ["import-verisig"]):
        run = without_extras(*command, "--help")
        assert run.returncode == 0, (command, run.stderr)
        assert "usage: percver" in run.stdout


def test_demo_without_matplotlib_keeps_the_result_and_says_how_to_plot(tmp_path):
    figure = tmp_path / "demo.png"
    run = without_extras("demo", "--out", str(figure), "--p0", "-0.5", "-0.4995", "--delta-c", "1.5", "1.6", "--no-progress")
    assert run.returncode == 0, run.stderr
    assert "verdict: verified" in run.stdout
    assert 'pip install "percver[plot]"' in run.stdout
    assert "extras loaded: []" in run.stdout
    assert not figure.exists()
    doc = json.loads(figure.with_suffix(".json").read_text())
    assert doc["verdict"] == "verified" and doc["row"]["intervals"] == 2 and doc["plot"] is None


def test_demo_help_is_plain_text():
    run = without_extras("demo", "--help")
    assert "``" not in run.stdout and ":func:" not in run.stdout
    assert "Exit status: 0 verified, 3 unknown, 4 falsified" in run.stdout


def test_version_is_the_project_version():
    declared = re.search(r'^version = "([^"]+)"', (ROOT / "pyproject.toml").read_text(), re.M).group(1)
    run = subprocess.run([sys.executable, "-m", "percver.cli", "--version"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == f"percver {declared}"
    assert percver.__version__ == declared


def test_package_is_typed():
    assert (PACKAGE / "py.typed").is_file()
    assert (PACKAGE / "_core.pyi").is_file()


def _stub_names(body) -> dict:
    """{name: None for a function or annotated constant, {method names} for a class} of a stub body."""
    out = {}
    for node in body:
        if isinstance(node, ast.ClassDef):
            out[node.name] = {n.name for n in node.body if isinstance(n, ast.FunctionDef)}
        elif isinstance(node, ast.FunctionDef):
            out[node.name] = None
        elif isinstance(node, ast.AnnAssign):
            out[node.target.id] = None
    return out


def test_core_stubs_declare_exactly_what_the_core_exports():
    stubs = _stub_names(ast.parse((PACKAGE / "_core.pyi").read_text()).body)
    exported = {n for n in dir(percver._core) if not n.startswith("__") or n == "__version__"}
    assert set(stubs) == exported
    for name, methods in stubs.items():
        cls = getattr(percver._core, name)
        if methods is None:
            continue
        own = {m for m in vars(cls) if not m.startswith("__")}
        declared = {m for m in methods if not m.startswith("__")}
        assert declared == own, f"{name}: stubs {sorted(declared - own)} not in the core, {sorted(own - declared)} not stubbed"
        dunders = {m for m in methods if m.startswith("__") and m != "__init__"}
        assert all(hasattr(cls, m) for m in dunders), name


def test_every_module_parses_as_python_3_9():
    """The package claims Python >= 3.9: no syntax newer than 3.9 (match, except*, ...)."""
    for path in sorted(PACKAGE.rglob("*.py")):
        ast.parse(path.read_text(), filename=str(path), feature_version=(3, 9))


def test_verify_config_reader_falls_back_to_tomli():
    source = (PACKAGE / "commands" / "verify.py").read_text()
    assert "import tomli as tomllib" in source
    requires = (ROOT / "pyproject.toml").read_text()
    assert "tomli>=1.1; python_version < '3.11'" in requires


@pytest.mark.parametrize("verdict, code", [("verified", 0), ("unknown", 3), ("falsified", 4)])
def test_demo_exit_status_is_the_verdict(verdict, code, monkeypatch, tmp_path, capsys):
    """The demo exits like `percver verify` (it exited 0 whatever the verdict)."""
    import percver as pv
    from percver.cases.mountain_car import verification
    from percver.cli import main
    from percver.verification import Cell

    box = {"p": (-0.5, -0.4995), "v": (0.0, 0.0), "dc": (1.5, 1.6), "r": (0.0, 0.0)}
    reason = "step 92: goal 'p >= 0.45' holds on part of the set only since step 89" if verdict == "unknown" else None
    cells = [Cell(box, verdict if verdict != "falsified" else "falsified", reason=reason)]
    monkeypatch.setattr(verification, "verify", lambda *a, **k: pv.Result(["p", "v", "dc", "r"], box, cells, 1.0))
    assert main(["demo", "--out", str(tmp_path / "d.png"), "--no-progress"]) == code
    out = capsys.readouterr().out
    assert f"verdict: {verdict}" in out
    if verdict == "unknown":
        assert "unknown: 1 cell at steps 92-92: goal met by part of the set only" in out
        assert "blew up" not in out
