"""``percver verify CONFIG.toml``: run ``pv.verify`` on a problem described in a TOML file.

The config names the plant and the property; paths in it are relative to the config file::

    [plant]                       # exactly one of python / model
    python = "loop.py:loop"       # a pv.ClosedLoop or loaded problem, or a function returning one
    model = "MC_sig_tmp.model"    # a Verisig 2.0 model (hybrid, DNN modes) or a Flow* continuous model
    networks = ["sig16x16.yml"]   # the Verisig model's networks, in command-line order
    period = 0.1                  # Flow* continuous models: step of the reach boxes (default: the file's step)

    [init]                        # initial box (models: default the file's); a number is a point
    p = [-0.53, -0.50]
    v = 0.0

    [split]                       # cells per state (an integer) or the largest cell width (a float)
    p = 3

{options}
    [output]
    json = "result.json"          # default (and --out): CONFIG.result.json in the current directory

Expressions use the Flow* syntax (``^`` for powers). Exit status: 0 verified, 3 unknown,
4 falsified, 1 bad input (one line on stderr), 2 bad usage.
"""

from __future__ import annotations

import argparse
import math
import re
import runpy
import sys
import warnings
from pathlib import Path

from percver.commands import EXIT
from percver.errors import InputError, MissingFileError, PercverError

if sys.version_info >= (3, 11):
    import tomllib
else:  # the same parser, from PyPI (a dependency on these Pythons)
    import tomli as tomllib

# pv.verify's keywords as config keys: (table, accepted TOML types, example value, meaning). The one
# source of the [property] and [verify] tables, of the example in ``--help`` and of the reference
# in docs/verify.md (``percver verify --config-reference``); a test checks it against pv.verify's
# signature. ``loop`` is [plant], ``init`` and ``split`` are tables of their own.
NUMBER = (int, float)
OPTIONS = {
    "steps": ("property", int, "150", "horizon in control steps (models: the file's)"),
    "goal": (
        "property",
        (str, list),
        '["p >= 0.45", "r + 100 > 90"]',
        "to reach: at the last step, or at some step with within; a list is a conjunction",
    ),
    "within": ("property", bool, "true", "the goal at some step up to steps (else at the last step)"),
    "safe": (
        "property",
        (str, list, dict),
        '["v >= -0.07", "v <= 0.07"]',
        "must hold at every step; a list is a conjunction; {conditions = [...], time = [t0, t1]} (or steps = [a, b]): in that window",
    ),
    "unsafe": (
        "property",
        (str, list, dict),
        '["p <= -1.3"]',
        "a set to avoid at every step; a list is one set, the conjunction of its conditions; a table as for safe: in a window",
    ),
    "reward": ("property", dict, '{r = "-0.1 * u^2"}', "accumulators: summed along the run from 0, readable in goal and safe"),
    "method": ("verify", str, '"taylor"', 'network propagation: "taylor" or "verisig"'),
    "order": ("verify", int, "5", "Taylor model order"),
    "max_splits": ("verify", int, "16", "in-cell splits and forks per cell (0: never)"),
    "refine": ("verify", bool, "true", "bisect unknown cells down to min_width"),
    "min_width": ("verify", dict, "{p = 0.005}", "smallest cell width per state for refine and timeouts (default: 1/64 of init)"),
    "rebox": ("verify", bool, "false", "restart a part from its box when a remainder is most of a state's enclosure"),
    "state_symbols": ("verify", bool, "false", "keep feedback remainders as error symbols (Taylor method)"),
    "timeout_per_cell": ("verify", NUMBER, "600", "seconds after which a cell stops at the next step and is bisected"),
    "time_limit": (
        "verify",
        NUMBER,
        "3600",
        "wall seconds for the whole run: then cells stop or are not run, reported unknown (--time-limit overrides)",
    ),
    "falsify": ("verify", int, "32", "random simulated runs per cell left unknown and not split further"),
    "seed": ("verify", int, "0", "seed of those runs"),
    "workers": ("verify", int, "2", "local threads (default: all cores; --workers overrides)"),
    "executor": ("verify", str, '"tcp://host:8786"', "a Dask scheduler to run the cells on (--scheduler overrides)"),
    "batch": ("verify", int, "8", "cells per executor task (default: sized to about a quarter second)"),
    "splitter": (
        "verify",
        (str, dict),
        '{kind = "adaptive", max_cells = 512}',
        'how cells are made: "grid", "bisection" or "adaptive" (pv.Grid, pv.Bisection, pv.Adaptive), '
        "or a table with kind and their keywords (instead of [split], refine, min_width)",
    ),
    "strict": ("verify", bool, "false", "an initial or reach set leaving a network's input domain is an error (else a warning)"),
    "validated": (
        "verify",
        dict,
        "{p = [-1.2, 0.6], v = [-0.07, 0.07]}",
        "where the model was validated, per state: the result says whether the reach sets stay inside (a diagnosed plant carries its own)",
    ),
    "journal": ("verify", str, '"run.jsonl"', "append finished cells here, skip them on a rerun (--journal overrides)"),
    "progress": ("verify", bool, "true", "the progress bar (--no-progress turns it off)"),
}
# Section -> key -> accepted types (None: any key, checked later); anything else is a typo worth an error.
SCHEMA = {
    "plant": {"python": str, "model": str, "networks": list, "period": NUMBER},
    "init": None,
    "split": None,
    **{table: {k: kind for k, (t, kind, _, _) in OPTIONS.items() if t == table} for table in ("property", "verify")},
    "output": {"json": str},
}


def example() -> str:
    """The [property] and [verify] tables of the example config, one line per option."""
    lines = []
    for table in ("property", "verify"):
        lines.append(f"    [{table}]")
        lines += [f"    {k} = {ex}".ljust(46) + f"# {meaning}" for k, (t, _, ex, meaning) in OPTIONS.items() if t == table]
        lines.append("")
    return "\n".join(lines)


def reference() -> str:
    """The config reference as a Markdown table: every option with its table, type and default."""
    import inspect

    from percver.verification import verify

    defaults = {k: p.default for k, p in inspect.signature(verify).parameters.items()}
    rows = ["| key | table | type | default | meaning |", "|---|---|---|---|---|"]
    for k, (table, kind, _, meaning) in OPTIONS.items():
        kinds = " or ".join(
            {"str": "string", "list": "list of strings", "dict": "table", "int": "integer", "float": "number", "bool": "boolean"}[
                t.__name__
            ]
            for t in (kind if isinstance(kind, tuple) else (kind,))
        )
        kinds = "number" if kind is NUMBER else kinds
        default = defaults[k]
        default = "-" if default is None else f"`{str(default).lower() if isinstance(default, bool) else default}`"
        rows.append(f"| `{k}` | [{table}] | {kinds} | {default} | {meaning} |")
    return "\n".join(rows) + "\n"


def register(sub) -> None:
    parser = sub.add_parser(
        "verify",
        help="verify a closed loop described in a TOML config (cells, falsification, refinement, journal)",
        description="Verify the closed loop of CONFIG.toml: split the initial set, falsify, verify each cell, "
        "print the summary table and write the result as JSON. Exit status: 0 verified, 3 unknown, 4 falsified, "
        "1 bad input.",
        epilog=__doc__.split("\n\n", 1)[1].replace("{options}\n", example()),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("config", nargs="?", help="the problem: plant, initial box, split, property, settings (TOML)")
    parser.add_argument("--config-reference", action="store_true", help="print every config option as a Markdown table and exit")
    parser.add_argument("--scheduler", metavar="ADDRESS", help="run the cells on a Dask scheduler, e.g. tcp://host:8786")
    parser.add_argument("--journal", metavar="PATH", help="append finished cells here and skip them on a rerun")
    parser.add_argument("--workers", type=int, metavar="N", help="local threads for the cells (default: all cores)")
    parser.add_argument(
        "--time-limit", type=float, metavar="SECONDS", help="wall seconds for the whole run; cells stopped or not run by then are unknown"
    )
    parser.add_argument("--out", metavar="PATH", help="result JSON (default: [output] json, else CONFIG.result.json)")
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    parser.add_argument("--json", action="store_true", help="print the result as JSON instead of the summary")
    parser.set_defaults(func=run)


def run(args) -> int:
    from percver.verification import verify

    if args.config_reference:
        print(reference(), end="")
        return 0
    if args.config is None:
        raise InputError("give a config file: percver verify CONFIG.toml (or --config-reference)")
    config = Config(args.config)
    kwargs = config.verify_kwargs()
    if args.journal:
        kwargs["journal"] = args.journal
    if args.workers is not None:
        kwargs["workers"] = args.workers
    if args.time_limit is not None:
        kwargs["time_limit"] = args.time_limit
    if args.scheduler:
        kwargs["executor"] = args.scheduler
    out = Path(args.out) if args.out else config.written("[output] json", config.section("output").get("json"))
    with warnings.catch_warnings():
        warnings.showwarning = lambda message, *_a, **_k: print(f"percver verify: warning: {message}", file=sys.stderr)
        kwargs["progress"] = kwargs.get("progress", True) and not args.no_progress and not args.json
        loop = config.checked(config.target(), kwargs)
        result = verify(loop, **kwargs)
    result.to_json(str(out))
    if args.json:
        print(result.to_json())
    else:
        print(report(result, loop))
        print(f"result: {out}")
    return EXIT[result.verdict]


def report(result, loop=None) -> str:
    """The summary table, then what decided the verdict (counterexample, or where precision ran
    out and what to try: :func:`percver.verification.advice.hints`, with float runs of ``loop``)."""
    lines = [
        result.summary(),
        f"verdict: {result.verdict} ({100 * result.coverage:.2f}% of the initial set verified, {result.seconds:.2f} s)",
    ]
    cex = result.counterexample
    if cex is not None:
        start = ", ".join(f"{k} = {v:.9g}" for k, v in cex.initial.items())
        lines.append(f"counterexample: from {start}: {cex.violated} fails at step {cex.step}")
    unknown = [c for c in result.cells if c.verdict == "unknown"]
    for c in unknown[:5]:
        box = ", ".join(f"{k} in [{lo:.6g}, {hi:.6g}]" for k, (lo, hi) in c.box.items())
        lines.append(f"unknown: {box}: {c.reason}")
    if len(unknown) > 5:
        lines.append(f"... and {len(unknown) - 5} more unknown cells (see the JSON)")
    lines += [f"try: {hint}" for hint in result.hints(loop)]
    return "\n".join(lines)


class Config:
    """A parsed config file; every check happens here, before any verification work."""

    def __init__(self, path: str):
        self.path = Path(path)
        if not self.path.is_file():
            raise MissingFileError(f"config file not found: {self.path}")
        try:
            self.doc = tomllib.loads(self.path.read_text())
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
            raise InputError(f"{self.path}: not valid TOML: {error}") from None
        for section, value in self.doc.items():
            if section not in SCHEMA:
                raise InputError(f"{self.path}: unknown section [{section}] (sections: {', '.join(SCHEMA)})")
            if not isinstance(value, dict):
                raise InputError(f"{self.path}: '{section}' must be a table, [{section}]")
            for key, item in value.items() if SCHEMA[section] else ():
                if key not in SCHEMA[section]:
                    raise self.error(f"[{section}]", f"unknown key '{key}' (known: {', '.join(SCHEMA[section])})")
                kind = SCHEMA[section][key]
                if not isinstance(item, kind) or isinstance(item, bool) is not (kind is bool):
                    names = " or ".join(t.__name__ for t in (kind if isinstance(kind, tuple) else (kind,)))
                    raise self.error(f"[{section}] {key}", f"expected {names}, got {item!r}")

    def section(self, name: str) -> dict:
        return self.doc.get(name, {})

    def error(self, field: str, message: str) -> InputError:
        return InputError(f"{self.path}: {field}: {message}")

    def file(self, field: str, value) -> Path:
        if not isinstance(value, str):
            raise self.error(field, f"expected a file name, got {value!r}")
        path = self.path.parent / value
        if not path.is_file():
            raise MissingFileError(f"{self.path}: {field}: file not found: {path}")
        return path

    def target(self):
        """The loop or loaded problem named by [plant]."""
        plant = self.section("plant")
        given = [k for k in ("python", "model") if k in plant]
        if len(given) != 1:
            raise self.error("[plant]", 'give exactly one of python = "FILE.py:NAME" or model = "FILE.model"')
        if given == ["python"]:
            if "networks" in plant or "period" in plant:
                raise self.error("[plant]", "networks and period belong to model = ..., not python = ...")
            return self._python(plant["python"])
        return self._model(plant)

    def _python(self, spec):
        from percver.systems import ClosedLoop

        path, colon, name = str(spec).rpartition(":")
        if not colon or not path.endswith(".py") or not name.isidentifier():
            raise self.error("[plant] python", f"'{spec}' is not FILE.py:NAME")
        file = self.file("[plant] python", path)
        sys.path.insert(0, str(file.parent))  # the file may import its neighbours
        try:
            namespace = runpy.run_path(str(file))
        finally:
            sys.path.remove(str(file.parent))
        if name not in namespace:
            raise self.error("[plant] python", f"{file} defines no '{name}'")
        obj = namespace[name]
        if callable(obj) and not isinstance(obj, ClosedLoop):
            obj = obj()
        if not isinstance(obj, ClosedLoop) and not isinstance(getattr(obj, "loop", None), ClosedLoop):
            raise self.error("[plant] python", f"'{spec}' is a {type(obj).__name__}, not a pv.ClosedLoop or a loaded problem")
        return obj

    def _model(self, plant: dict):
        from percver import formats
        from percver.translation import load_verisig

        model = self.file("[plant] model", plant["model"])
        networks = plant.get("networks", [])
        nets = [str(self.file(f"[plant] networks[{i}]", n)) for i, n in enumerate(networks)]
        if re.match(r"\s*continuous\s+reachability", model.read_text(errors="replace")):
            if nets:
                raise self.error("[plant] networks", f"{model.name} is a continuous Flow* model without networks")
            return FlowstarProblem(formats.load_flowstar(str(model)), plant.get("period"))
        if "period" in plant:
            raise self.error("[plant] period", "Verisig models carry their own control period")
        return load_verisig(str(model), networks=nets)

    def checked(self, target, kwargs: dict):
        """``target`` if there is a property to verify: the config's, or the model file's own."""
        own = getattr(target, "defaults", {})
        given = [source.get(k) for source in (kwargs, own) for k in ("goal", "safe", "unsafe")]
        if all(v is None or (isinstance(v, list) and not v) for v in given):
            raise self.error("[property]", 'nothing to verify: give goal = "...", safe = [...] or unsafe = [...] (e.g. goal = "p >= 0.45")')
        return target

    def verify_kwargs(self) -> dict:
        """pv.verify's keyword arguments from [init], [split], [property], [verify]."""
        from percver.systems import condition

        kwargs: dict = {}
        if "init" in self.doc:
            for name, value in self.section("init").items():
                if not _number(value) and not (isinstance(value, list) and len(value) == 2 and all(map(_number, value))):
                    raise self.error(f"[init] {name}", f"expected [lo, hi] or a number, got {value!r}")
                lo, hi = value if isinstance(value, list) else (value, value)
                if not (math.isfinite(lo) and math.isfinite(hi)):
                    raise self.error(f"[init] {name}", f"the bounds must be finite numbers, got {value!r}")
                if lo > hi:
                    raise self.error(f"[init] {name}", f"lower bound {lo!r} is above upper bound {hi!r}; write [{hi!r}, {lo!r}]")
            kwargs["init"] = self.section("init")
        if "split" in self.doc:
            split = self.section("split")
            for name, value in split.items():
                if not _number(value):
                    raise self.error(f"[split] {name}", f"expected a cell count (integer) or width (float), got {value!r}")
            kwargs["split"] = split
        prop = dict(self.section("property"))
        if "steps" in prop:
            kwargs["steps"] = prop.pop("steps")
        if "within" in prop:
            kwargs["within"] = prop.pop("within")
        for key in ("goal", "safe", "unsafe"):
            if key in prop:
                items = prop.pop(key)
                items = items if isinstance(items, list) else [items]
                kwargs[key] = [
                    self._window(f"[property] {key}", t) if isinstance(t, dict) else self._parsed(f"[property] {key}", t, condition)
                    for t in items
                ]
        if "reward" in prop:
            kwargs["reward"] = {k: self._parsed(f"[property] reward.{k}", v, _expression) for k, v in prop.pop("reward").items()}
        kwargs.update(self.section("verify"))
        if "splitter" in kwargs:
            kwargs["splitter"] = self._splitter(kwargs["splitter"])
        if "validated" in kwargs:
            from percver.validate.verifiable import Domain

            bounds = kwargs["validated"]
            bad = [k for k, v in bounds.items() if not (isinstance(v, list) and len(v) == 2 and all(map(_number, v)))]
            if bad:
                raise self.error("[verify] validated", f"expected {bad[0]} = [lo, hi]")
            kwargs["validated"] = Domain({k: (float(v[0]), float(v[1])) for k, v in bounds.items()})
        if "journal" in kwargs:
            kwargs["journal"] = str(self.written("[verify] journal", kwargs["journal"]))
        return kwargs

    def written(self, field: str, value) -> Path:
        """A file the run writes: relative to the config; the result JSON defaults to CONFIG.result.json here."""
        if value is None:
            return Path(f"{self.path.stem}.result.json")
        if not (self.path.parent / value).parent.is_dir():
            raise self.error(field, f"the directory of {self.path.parent / value} does not exist")
        return self.path.parent / value

    def _splitter(self, spec):
        """``"adaptive"`` or ``{kind = "adaptive", max_cells = 512, ...}`` as the splitter object."""
        from percver.verification.splitters import Adaptive, Bisection, Grid

        kinds = {"grid": Grid, "bisection": Bisection, "adaptive": Adaptive}
        table = {"kind": spec} if isinstance(spec, str) else dict(spec)
        kind = table.pop("kind", None)
        if kind not in kinds:
            raise self.error("[verify] splitter", f"kind must be one of {', '.join(kinds)}, got {kind!r}")
        try:
            return kinds[kind](**table)
        except TypeError as error:
            raise self.error("[verify] splitter", f"{kind}: {error}") from None
        except PercverError as error:
            raise self.error("[verify] splitter", str(error)) from None

    def _window(self, field: str, table: dict):
        """``{conditions = [...], time = [t0, t1]}`` (or ``steps = [first, last]``; one number: to
        the horizon) as ``pv.during(all of the conditions, ...)``."""
        from percver.properties import all_of, during
        from percver.systems import condition

        keys = set(table)
        if "conditions" not in keys or len(keys & {"time", "steps"}) != 1 or keys - {"conditions", "time", "steps"}:
            raise self.error(
                field, f'a window is {{conditions = ["x1 >= 0", ...], time = [t0, t1]}} or steps = [first, last]; got {table!r}'
            )
        texts = table["conditions"] if isinstance(table["conditions"], list) else [table["conditions"]]
        conds = [self._parsed(f"{field} conditions", t, condition) for t in texts]
        unit = "time" if "time" in table else "steps"
        span = table[unit]
        if not (isinstance(span, list) and len(span) in (1, 2) and all(map(_number, span))):
            raise self.error(f"{field} {unit}", f"expected [start, end] or [start] (to the horizon), got {span!r}")
        try:
            return during(all_of(conds), **{unit: (span[0], span[1] if len(span) == 2 else None)})
        except PercverError as error:
            raise self.error(field, str(error)) from None

    def _parsed(self, field: str, text, parse):
        if not isinstance(text, str):
            raise self.error(field, f'expected a string such as "p >= 0.45", got {text!r}')
        try:
            return parse(text)
        except PercverError as error:
            raise self.error(field, str(error)) from None


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _expression(text: str):
    from percver.expr import parse

    return parse(text)


class FlowstarProblem:
    """A Flow* continuous model as a problem for ``pv.verify``: its ODE as a plant without stages,
    reach boxes every ``period`` (default: the file's step) up to the file's time horizon, the
    file's initial set; the property comes from the config (Flow* files have none)."""

    def __init__(self, model, period=None):
        from percver.expr import parse
        from percver.systems import ClosedLoop, Continuous

        step = model.step[1] if isinstance(model.step, tuple) else model.step
        self.period = float(step if period is None else period)
        if not self.period > 0:
            raise InputError(f"{model.path}: the period must be positive, got {self.period}")
        self.steps = max(1, round(model.t_end / self.period))
        plant = Continuous(
            {v: parse(model.odes[v]) for v in model.variables},
            period=self.period,
            step=min(step, self.period),
            remainder=max(model.remainder),
        )
        self.loop = ClosedLoop(plant)
        self.defaults = {"init": dict(model.init), "steps": self.steps}
