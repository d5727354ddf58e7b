"""Network domains in a verification: where the initial set or a reach set leaves the input range
a network stage was trained on (:attr:`percver.Network.domain`). The proof still holds for the
network as given, but there it extrapolates, so it may be about a function nobody checked."""

from __future__ import annotations

import warnings
from typing import Optional

import numpy as np

from percver.errors import NetworkDomainError
from percver.systems import ClosedLoop, InputRangeWarning


class DomainWarning(InputRangeWarning):
    """The initial set or a reach set leaves the input domain of a network stage (the range it
    was trained on, :attr:`percver.Network.domain`): the proof is about the network's
    extrapolation there. ``verify(strict=True)`` makes it a :class:`~percver.errors.NetworkDomainError`."""


def domain_checks(loop: ClosedLoop) -> list:
    """(stage, network, input, state column, (lo, hi)) for each bounded domain entry of a network
    stage whose input is a state. Inputs computed by earlier stages (an image, an estimate) are not
    checked: the engine keeps boxes of the states only."""
    checks = []
    for stage, indices in zip(loop.stages, loop.stage_inputs):
        domain = stage.component.domain if stage.is_network else None
        for index, (lo, hi) in zip(indices, domain or ()):
            if index < len(loop.states) and (lo > -np.inf or hi < np.inf):
                checks.append((stage.name, stage.component.name, loop.env_names[index], index, (lo, hi)))
    return checks


def runs(cells: list, states: list) -> list:
    """Each cell's per-step boxes as a (steps + 1, states, 2) array; its initial box alone when it has none."""
    return [np.asarray(c.boxes if c.boxes else [[c.box[n] for n in states]], dtype=float) for c in cells]


def domain_exits(checks: list, boxes: list) -> list:
    """Per checked input that some run (per-step boxes) leaves: the first step, the input's box over
    the runs leaving there, the domain and how many runs leave it at any step."""
    exits = []
    for stage, network, name, column, (lo, hi) in checks:
        first, at_first, count = None, [], 0
        for run in boxes:
            b = run[:, column]
            out = np.flatnonzero((b[:, 0] < lo) | (b[:, 1] > hi))
            if len(out) == 0:
                continue
            count += 1
            step = int(out[0])
            if first is None or step < first:
                first, at_first = step, [b[step]]
            elif step == first:
                at_first.append(b[step])
        if count:
            box = (float(min(b[0] for b in at_first)), float(max(b[1] for b in at_first)))
            exits.append({"stage": stage, "network": network, "input": name, "step": first, "box": box, "domain": (lo, hi), "cells": count})
    return exits


def merged_exits(exits: list) -> list:
    """The exits of several results over parts of one initial set (a case's bands) as one result's:
    per checked input, the earliest step, the hull of the boxes at that step, and the runs summed."""
    merged = {}
    for e in exits:
        key = (e["stage"], e["network"], e["input"], tuple(e["domain"]))
        have = merged.get(key)
        if have is None or e["step"] < have["step"]:
            merged[key] = {**e, "cells": e["cells"] + (have["cells"] if have else 0)}
        else:
            box = (min(have["box"][0], e["box"][0]), max(have["box"][1], e["box"][1])) if e["step"] == have["step"] else have["box"]
            merged[key] = {**have, "box": box, "cells": have["cells"] + e["cells"]}
    return list(merged.values())


def flag_exits(exits: list, strict: bool, results: Optional[list] = None) -> None:
    """Warn of the exits (:class:`DomainWarning`), or raise them with ``strict``; ``results`` (None
    before the run) go with the error."""
    if not exits:
        return
    where = "; ".join(
        f"stage '{e['stage']}' (network '{e['network']}'): {e['input']} in [{e['box'][0]:g}, {e['box'][1]:g}] at step {e['step']}"
        f"{' (the initial set)' if e['step'] == 0 else ''} leaves [{e['domain'][0]:g}, {e['domain'][1]:g}]"
        for e in exits
    )
    message = (
        f"{where}: outside the input domain the network was trained on, so the result is about its "
        "extrapolation there; narrow the initial set or give a network trained on this range"
    )
    if strict:
        error = NetworkDomainError(message)
        error.results = results
        raise error
    warnings.warn(message + " (strict=True makes this an error)", DomainWarning, stacklevel=4)
