"""What to try when cells stay unknown: changes of ``pv.verify``'s keywords read from the evidence
the unknown cells carry (the engine's reason, the options each ran with, its reach boxes and,
given the loop, float runs from the cell), each with the numbers behind it. A hint is not a
verdict: following one costs a run, and the cells may still end unknown."""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Optional


from percver.errors import InputError
from percver.systems import ClosedLoop
from percver.verification.splitters import GOAL_PART, PRECISION_LOST, TIME_LIMIT
from percver.verification.wrapping import EXAMINED, wrapping

SPLITS = re.compile(r"\(after (\d+) splits\)")


@dataclass(frozen=True)
class Hint:
    """``keywords`` to pass to ``pv.verify`` (e.g. ``{"state_symbols": True}``), why, and on how
    many unknown cells that evidence was found."""

    keywords: dict
    why: str
    cells: int

    def __str__(self) -> str:
        given = ", ".join(f"{k}={v!r}" for k, v in self.keywords.items())
        return f"{given}: {self.why} ({self.cells} unknown cell{'s' if self.cells != 1 else ''})"


def hints(result, loop: Optional[ClosedLoop] = None) -> list:
    """The :class:`Hint` list for ``result``'s unknown cells (none for a verified or falsified
    result). Without ``loop`` the reach boxes are not compared with float runs, so loose
    enclosures are not looked for."""
    if result.verdict != "unknown":
        return []
    loop = getattr(loop, "loop", loop)  # a loaded Verisig or Flow* problem carries its loop
    if loop is not None and not isinstance(loop, ClosedLoop):
        raise InputError(f"hints(loop=...) takes the pv.ClosedLoop (or loaded problem) that was verified, got {type(loop).__name__}")
    unknown = [c for c in result.cells if c.verdict == "unknown"]
    settings = result.settings
    out = []
    limited = [c for c in unknown if TIME_LIMIT in (c.reason or "")]
    if limited and settings.get("time_limit"):
        limit = settings["time_limit"]
        out.append(
            Hint(
                {"time_limit": 4 * limit},
                f"cells stopped or not run at the call's {limit:g} s limit (first: '{limited[0].reason}'); "
                "with the same journal= a rerun resumes from the cells that finished",
                len(limited),
            )
        )
    timed = [c for c in unknown if (c.reason or "").startswith("timeout after")]
    if timed and settings.get("timeout_per_cell"):
        limit = settings["timeout_per_cell"]
        out.append(Hint({"timeout_per_cell": 4 * limit}, f"cells stopped at the {limit:g} s limit ({timed[0].reason})", len(timed)))
    lost = [c for c in unknown if any(words in (c.reason or "") for words in PRECISION_LOST)]
    plain = [c for c in lost if not (c.options.get("rebox") or settings.get("rebox"))]
    if plain:
        out.append(
            Hint(
                {"rebox": True},
                f"an operation left its domain or an enclosure blew up, never restarted from boxes (first: '{plain[0].reason}'); "
                "reboxed, a part restarts from its box whenever remainders are most of a state's enclosure, so they stop feeding back",
                len(plain),
            )
        )
    used_up = [c for c in unknown if _splits_used_up(c, settings)]
    if used_up:
        most = max(int(SPLITS.search(c.reason).group(1)) for c in used_up)
        arrivals = sum(GOAL_PART in c.reason for c in used_up)
        why = f"cells gave up after all of their {most} in-cell splits and forks (first: '{used_up[0].reason}')"
        if arrivals:
            why += f"; in {arrivals} of them parts of the cell reach the goal at different steps, one fork each"
        out.append(Hint({"max_splits": 4 * most}, why, len(used_up)))
    if isinstance(loop, ClosedLoop):
        out += _loose(unknown, loop, settings) or _loose(result.lost, loop, settings, replaced=True)
    return out


def _splits_used_up(cell, settings: dict) -> bool:
    found = SPLITS.search(cell.reason or "")
    budget = cell.options.get("max_splits", settings.get("max_splits"))
    return found is not None and budget is not None and int(found.group(1)) >= budget > 0


def _loose(unknown: list, loop: ClosedLoop, settings: dict, replaced: bool = False) -> list:
    """Cells (of the first ``EXAMINED`` that ran) whose enclosure ended ``LOOSE`` times wider than their
    float runs and grew ``GROWTH`` times a step before that: the errors of a step were fed back
    into the next (the wrapping effect), which symbols for the states' errors (or boxes to restart
    from) stop. Each is named from the cells that ran without it (the adaptive splitter may have
    given a cell either)."""
    found = []
    ran = [c for c in unknown if c.boxes]  # cells not run (a time limit) carry no evidence
    for cell in ran[:EXAMINED]:
        evidence = wrapping(loop, cell)
        if evidence is not None:
            found.append((cell, evidence))
    # With ``replaced``, none of the cells left carried evidence, and those the splitter halved or retried did.
    where = "a cell the splitter then replaced" if replaced else "its cell"
    out = []
    remedies = (
        ("state_symbols", "kept as symbols from step to step, the controller's corrections cancel them"),
        ("rebox", "reboxed, a part restarts from its box whenever remainders dominate"),
    )
    for option, remedy in remedies:
        if settings.get(option) or (option == "state_symbols" and settings.get("method", "taylor") != "taylor"):
            continue
        without = [e for cell, e in found if not cell.options.get(option)]
        if not without:
            continue
        state, ratio, growth, step, runs = max(without, key=lambda e: e[1])
        why = (
            f"the enclosure of {state} was {ratio:.0f} times the spread of {runs} float runs from {where} at step {step}, "
            f"after growing {growth:.2f} times a step: errors fed back through the loop (wrapping); {remedy}"
        )
        out.append(Hint({option: True}, why, len(without)))
    return out
