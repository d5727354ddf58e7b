"""The paper's perception chain by name: ``y = g_n(x, g_c(x), delta)``, ``u = h(y)``.

A closed loop is a list of :class:`percver.Stage`; this names the roles a perception-based loop
is made of, so that a reader finds the canonical sensor, the noise model and the controller
without tracing signal names, and so that a chain with a missing or misplaced role is refused
with the role's name:

- ``canonical``: g_c, the state to the clean measurement (a ray caster, a renderer, a generator);
- ``noiser``: g_n, one or more stages that turn the clean measurement into the noisy one
  (generative networks with a noise input delta; classifiers and their knock-out decisions);
- ``denoiser``: optional, the noisy measurement back to a clean one;
- ``estimator``: optional, the measurement to a state estimate;
- ``controller``: h, the estimate (or measurement) to the control.

``pv.ClosedLoop(plant, perception)`` takes it where a list of stages goes (it iterates over its
stages in that order); stages after the controller (e.g. a plant's step computed as a stage) are
``then``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

from percver.errors import InputError
from percver.systems import Stage


@dataclass(frozen=True)
class Perception:
    canonical: Stage
    controller: Stage
    noiser: Sequence[Stage] = ()
    denoiser: Optional[Stage] = None
    estimator: Optional[Stage] = None
    then: Sequence[Stage] = ()

    def __post_init__(self):
        if isinstance(self.noiser, Stage):
            object.__setattr__(self, "noiser", (self.noiser,))
        if isinstance(self.then, Stage):
            object.__setattr__(self, "then", (self.then,))
        for role, stage in self.roles():
            if not isinstance(stage, Stage):
                raise InputError(f"Perception's {role} must be a pv.Stage, got {type(stage).__name__}")
        roles = self.roles()
        for k, (role, stage) in enumerate(roles):
            later = {s.output: r for r, s in roles[k:]}
            early = [name for name in stage.input_names if name in later]
            if early:
                raise InputError(
                    f"Perception's {role} reads '{early[0]}', which the {later[early[0]]} writes later in the chain "
                    "(order: canonical, noiser, denoiser, estimator, controller, then)"
                )

    def roles(self) -> list:
        """``(role, stage)`` in the order the loop evaluates them."""
        out = [("canonical", self.canonical)]
        out += [(f"noiser[{k}]", s) for k, s in enumerate(self.noiser)]
        out += [(role, s) for role, s in (("denoiser", self.denoiser), ("estimator", self.estimator)) if s is not None]
        out.append(("controller", self.controller))
        out += [(f"then[{k}]", s) for k, s in enumerate(self.then)]
        return out

    def __iter__(self):
        return iter([stage for _, stage in self.roles()])

    def role(self, output: str) -> Optional[str]:
        """The role of the stage that writes ``output`` (None if no stage does)."""
        return next((role for role, stage in self.roles() if stage.output == output), None)
