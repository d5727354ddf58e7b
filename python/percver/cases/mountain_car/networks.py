"""The five networks of the Mountain Car chain, from the paper's authors or trained by this package.

``load("paper")`` reads the authors' Verisig files from ``../shared/data/mountain_car/networks``
(next to the repository, or wherever ``shared=`` points); ``load("ours")`` reads the ONNX files
shipped in ``percver/cases/mountain_car/data`` (trained by :mod:`percver.cases.mountain_car.training`,
command and seed in ``networks.json`` there); ``load(DIR)`` reads a directory written by training.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from percver.cases.mountain_car import dynamics
from percver.cases.mountain_car.camera import PIXELS
from percver.errors import InputError, MissingFileError
from percver.formats import load_network
from percver.networks import Network

ROLES = ("generator", "contrast", "blur", "estimator", "controller")
PAPER_FILES = {
    "generator": "Generator2x50_100_Decay1TestLoss1.035e-06.yml",
    "contrast": "Contraster1x50_Decay5TestLoss47.74.yml",
    "blur": "Blurer1x50_Decay10TestLoss47.28.yml",
    "estimator": "CompositeRegressor3x20_20_20_Decay0.001TestLoss5.15e-06Composite.yml",
    "controller": "ControllerSigmoid16x16.yml",
}
OUR_FILES = {role: f"{role}.onnx" for role in ROLES}
# The authors' estimator outputs tanh; the position estimate is this map of it (Appendix A.4).
ESTIMATE_SCALE, ESTIMATE_OFFSET = 0.9, -0.3
PACKAGED = Path(__file__).resolve().parent / "data"
# Inputs and outputs of each role: (n_in, n_out).
SHAPES = {"generator": (1, PIXELS), "contrast": (PIXELS + 1, PIXELS), "blur": (PIXELS + 1, PIXELS),
          "estimator": (PIXELS, 1), "controller": (2, 1)}  # fmt: skip


def training_domain(role: str) -> list:
    """The input range each role's training data was drawn from (:mod:`percver.cases.mountain_car.training`):
    positions over [P_MIN, P_MAX], pixels in [0, 1], noise levels over the row's range, velocities
    within +-V_MAX. Training writes it into each ONNX file as the network's ``domain``."""
    p, pixel = (dynamics.P_MIN, dynamics.P_MAX), (0.0, 1.0)
    domains = {
        "generator": [p],
        "contrast": [pixel] * PIXELS + [dynamics.CONTRAST_RANGE],
        "blur": [pixel] * PIXELS + [dynamics.BLUR_RANGE],
        "estimator": [pixel] * PIXELS,
        "controller": [p, (-dynamics.V_MAX, dynamics.V_MAX)],
    }
    if role not in domains:
        raise InputError(f"unknown model role '{role}'; roles are {list(ROLES)}")
    return domains[role]


# The authors' data (their networks, published logs, the F1/10 study's files) is research data under
# its own licences: percver never ships it. The project keeps it read-only beside the repository.
SHARED_HINT = (
    "the authors' data is not part of the percver package: it sits read-only beside the repository as "
    "../shared/data; set PERCVER_SHARED=/path/to/shared/data, or pass shared=PATH (CLI: --shared PATH)"
)


def default_shared() -> Path:
    """The shared data: ``$PERCVER_SHARED``, else the first ``shared/data`` beside the working
    directory or one of its parents (a checkout next to ``../shared``), else beside the source tree
    this package runs from (editable installs); else ``../shared/data`` from the working directory,
    which does not exist (the callers' errors then say where they looked and :data:`SHARED_HINT`)."""
    if os.environ.get("PERCVER_SHARED"):
        return Path(os.environ["PERCVER_SHARED"])
    here = Path(__file__).resolve()
    for folder in (Path.cwd(), *Path.cwd().parents, *here.parents):
        for candidate in (folder / "shared" / "data", folder.parent / "shared" / "data"):
            if (candidate / "mountain_car" / "networks" / PAPER_FILES["generator"]).is_file():
                return candidate
    return Path.cwd().parent / "shared" / "data"


def paper_dir(shared=None) -> Path:
    """The folder of the authors' networks: ``shared`` may be that folder, ``.../shared/data`` or ``.../shared``."""
    base = Path(shared) if shared is not None else default_shared()
    for folder in (base, base / "mountain_car" / "networks", base / "data" / "mountain_car" / "networks"):
        if (folder / PAPER_FILES["generator"]).is_file():
            return folder
    raise MissingFileError(
        f"the authors' Mountain Car networks are not in {base} (looked for {PAPER_FILES['generator']} there, "
        f"in mountain_car/networks and in data/mountain_car/networks): {SHARED_HINT}; "
        "or use percver's shipped networks: networks='ours' (CLI: --networks ours)"
    )


@dataclass(frozen=True)
class Networks:
    """The chain: ``generator`` p -> image (600); ``contrast``, ``blur`` (image, delta) -> image;
    ``estimator`` image -> position estimate (the 0.9 out - 0.3 map included); ``controller`` (p_hat, v) -> u.
    """

    generator: Network
    contrast: Network
    blur: Network
    estimator: Network
    controller: Network
    name: str = "networks"
    source: Path | None = None

    def __post_init__(self):
        for role in ROLES:
            network = getattr(self, role)
            if (network.n_in, network.n_out) != SHAPES[role]:
                raise InputError(
                    f"{self.name}: the {role} network {network.name!r} maps {network.n_in} -> {network.n_out} values, "
                    f"the Mountain Car chain needs {SHAPES[role][0]} -> {SHAPES[role][1]}"
                )

    def with_networks(self, **networks: Network) -> "Networks":
        """A copy with some roles replaced (e.g. the authors' controller on our perception)."""
        unknown = sorted(set(networks) - set(ROLES))
        if unknown:
            raise InputError(f"unknown network role(s) {unknown}; roles are {list(ROLES)}")
        return replace(self, **networks)

    def images(self, positions, delta_c=None, delta_b=None) -> np.ndarray:
        """Model images (n, 600): ``g_c``, then ``g_ct(., delta_c)`` and/or ``g_b(., delta_b)`` (contrast first)."""
        positions = np.atleast_1d(np.asarray(positions, dtype=float))
        images = self.generator(positions[:, None])
        for network, delta in ((self.contrast, delta_c), (self.blur, delta_b)):
            if delta is not None:
                images = network(np.column_stack([images, np.broadcast_to(np.asarray(delta, dtype=float), len(positions))]))
        return images

    def estimate(self, images) -> np.ndarray:
        """Position estimates (n,) of images (n, 600) or (n, 20, 30)."""
        images = np.asarray(images, dtype=float)
        return self.estimator(images.reshape(len(images), PIXELS))[:, 0]

    def control(self, p_hat, v) -> np.ndarray:
        """Thrust (n,) from position estimates and velocities."""
        return self.controller(np.column_stack([np.ravel(p_hat), np.ravel(v)]))[:, 0]


def _paper(folder: Path) -> dict:
    loaded = {role: load_network(folder / name) for role, name in PAPER_FILES.items()}
    raw = loaded["estimator"]
    loaded["estimator"] = Network(raw.layers, scale=ESTIMATE_SCALE, offset=ESTIMATE_OFFSET, name=raw.name, source=raw.source)
    return loaded


def _ours(folder: Path, roles=ROLES) -> dict:
    missing = [OUR_FILES[role] for role in roles if not (folder / OUR_FILES[role]).is_file()]
    if missing:
        raise MissingFileError(
            f"{folder} lacks {missing}; train them with `percver cases mountain-car train --out {folder}` (or pick another network set)"
        )
    return {role: load_network(folder / OUR_FILES[role]) for role in roles}


def _resolve(spec, shared) -> tuple[str, Path]:
    if spec == "paper":
        return "paper", paper_dir(shared)
    if spec == "ours":
        return "ours", PACKAGED
    folder = Path(spec)
    if not folder.is_dir():
        raise MissingFileError(f"networks '{spec}' is neither 'paper', 'ours' nor an existing directory")
    if (folder / PAPER_FILES["generator"]).is_file():
        return "paper", folder
    return "ours", folder


def load(networks="ours", *, controller=None, shared=None) -> Networks:
    """The chain's networks: ``"ours"`` (shipped with percver), ``"paper"`` (the authors', from the shared
    data), or a directory of either kind. ``controller`` takes the controller from another set
    ("paper", "ours", a directory, or a network file); ``shared`` locates the shared data for "paper".
    """
    if isinstance(networks, Networks):
        chosen = networks
    else:
        kind, folder = _resolve(networks, shared)
        loaded = _paper(folder) if kind == "paper" else _ours(folder)
        chosen = Networks(**loaded, name=str(networks), source=folder)
    if controller is None:
        return chosen
    path = Path(str(controller))
    if path.is_file():
        other = load_network(path)
    else:
        kind, folder = _resolve(controller, shared)
        other = (_paper(folder) if kind == "paper" else _ours(folder, ("controller",)))["controller"]
    return replace(chosen.with_networks(controller=other), name=f"{chosen.name} (controller: {controller})")


def provenance(networks="ours") -> dict:
    """The ``networks.json`` record (commands, seed, losses, times) of a trained set ("ours" or a
    directory); empty for a set without one, such as the authors'."""
    path = (PACKAGED if networks == "ours" else Path(networks)) / "networks.json"
    return json.loads(path.read_text()) if path.is_file() else {}
