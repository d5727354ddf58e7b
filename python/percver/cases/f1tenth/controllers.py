"""The 12 end-to-end controllers of HSCC'20: 21 normalised rays -> steering.

Input: each range clipped at 5 m and normalised as (r - 2.5) / 5 (``world.normalise``).
Output: one tanh value; steering = 15 degrees x output (``u := 0.2618 * f1`` in the Verisig
glue), clipped to +-15 degrees.
"""

from __future__ import annotations

import numpy as np

from percver.cases.f1tenth import world
from percver.cases.f1tenth.data import controller_file
from percver.cases.f1tenth.dynamics import MAX_STEERING
from percver.errors import InputError

# Rows of ControllerOuputsOnRealData.npy.
NAMES = tuple(f"{algo}_L21_{size}x{size}_C{k}" for algo in ("DDPG", "TD3") for size in (64, 128) for k in (1, 2, 3))
# The controller the paper verifies and uses for its control-based evaluation.
VERIFIED = "TD3_L21_64x64_C2"


def short_name(name: str) -> str:
    """``DDPG_L21_64x64_C1`` -> ``DDPG_64_1``, the keys of ``crashes_by_controller.yml``."""
    algo, _, size, k = name.split("_")
    return f"{algo}_{size.split('x')[0]}_{k.lstrip('C')}"


class Controller:
    """A controller network with the car's input and output conventions."""

    def __init__(self, network, name: str | None = None):
        if network.n_in != 21 or network.n_out != 1:
            raise InputError(f"an F1/10 controller maps 21 rays to 1 output, '{network.name}' maps {network.n_in} -> {network.n_out}")
        self.network = network
        self.name = name or network.name

    def raw(self, ranges) -> np.ndarray:
        """Network outputs (N,) for 21-ray scans in metres."""
        return self.network(world.normalise(np.atleast_2d(ranges)))[:, 0]

    def __call__(self, ranges) -> np.ndarray:
        """Steering angles (N,) in radians."""
        return np.clip(MAX_STEERING * self.raw(ranges), -MAX_STEERING, MAX_STEERING)

    def __repr__(self) -> str:
        return f"Controller({self.name!r})"


def load(name: str, data=None) -> Controller:
    from percver.formats import load_network

    if name not in NAMES:
        raise InputError(f"unknown F1/10 controller '{name}'; the 21-ray controllers are {', '.join(NAMES)}")
    return Controller(load_network(controller_file(name, data)), name)


def load_all(names=None, data=None) -> dict:
    """``{name: Controller}`` for ``names`` (default: all 12, in ``NAMES`` order)."""
    return {name: load(name, data) for name in (names or NAMES)}
