"""``percver import-verisig MODEL.model NET.yml ... -o CONFIG.toml``: a ``percver verify`` config for
a Verisig 2.0 benchmark, with the file's initial set and horizon written out to edit.

The model is translated once here (``pv.load_verisig``), so a file percver cannot read
fails now, with file and line, rather than when the campaign starts. The config keeps the model's
own property (its ``unsafe`` block) unless ``[property]`` overrides it.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

from percver.errors import InputError


def register(sub) -> None:
    parser = sub.add_parser(
        "import-verisig",
        help="write a `percver verify` config for a Verisig 2.0 model and its networks",
        description="Translate a Verisig 2.0 closed-loop model (Flow* hybrid file with DNN modes) and write a "
        "TOML config that `percver verify` runs: the model, its networks, initial set and horizon.",
    )
    parser.add_argument("model", help="the Verisig model (e.g. MC_small_sig_tmp.model)")
    parser.add_argument("nets", nargs="*", metavar="NET.yml", help="its networks, in Verisig's command-line order")
    parser.add_argument("--networks", nargs="+", default=[], metavar="NET.yml", help="the networks (same as positional)")
    parser.add_argument("-o", "--out", metavar="CONFIG.toml", help="config to write (default: MODEL's stem + .toml here)")
    parser.add_argument("--force", action="store_true", help="overwrite an existing config")
    parser.add_argument("--json", action="store_true", help="print what was written as JSON")
    parser.set_defaults(func=run)


def run(args) -> int:
    from percver.translation import load_verisig

    networks = [*args.nets, *args.networks]
    problem = load_verisig(args.model, networks=networks)
    out = Path(args.out or f"{Path(args.model).stem}.toml")
    if out.exists() and not args.force:
        raise InputError(f"{out} exists; pass --force to overwrite it or -o to write elsewhere")
    out.write_text(config_text(problem, Path(args.model), [Path(n) for n in networks], out))
    if args.json:
        print(
            json.dumps(
                {
                    "config": str(out),
                    "model": args.model,
                    "networks": networks,
                    "states": problem.states,
                    "init": problem.init,
                    "steps": problem.steps,
                    "kind": problem.kind,
                }
            )
        )
    else:
        print(problem.summary())
        print(f"wrote {out}; run: percver verify {out}")
    return 0


def config_text(problem, model: Path, networks: list, out: Path) -> str:
    """The TOML config; file paths relative to the config's directory, as `percver verify` reads them."""

    def rel(p: Path) -> str:
        # Relative when the file sits below the config's directory (they move together), else absolute.
        r = os.path.relpath(p.resolve(), out.resolve().parent)
        return str(p.resolve()) if r.startswith("..") else r

    lines = [
        f"# percver verify config for {model.name}, written by percver import-verisig.",
        *(f"# {line}" for line in problem.summary().splitlines()),
        "",
        "[plant]",
        f"model = {_toml(rel(model))}",
        f"networks = {_toml([rel(n) for n in networks])}",
        "",
        "[init]",
        *(f"{_key(k)} = {_toml(list(v))}" for k, v in problem.init.items()),
        "",
        "[split]  # cells per state (an integer) or the largest cell width (a float), e.g.",
        f"# {_key(problem.states[0])} = 4",
        "",
        "[property]  # the model's own property (its unsafe block) unless goal/safe/unsafe are given here",
        f"steps = {problem.steps}",
        "",
        "[verify]",
        'method = "taylor"  # or "verisig"',
        "order = 5",
        "refine = false",
        "",
    ]
    return "\n".join(lines)


def _key(name: str) -> str:
    return name if re.fullmatch(r"[A-Za-z0-9_-]+", name) else json.dumps(name)


def _toml(value) -> str:
    """A TOML value for strings, numbers and lists of them (JSON's string escapes are TOML's)."""
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, float):
        return repr(value)
    return json.dumps(value)
