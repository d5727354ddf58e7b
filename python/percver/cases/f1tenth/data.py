"""Where the original study's files are, and the statistics of its real runs.

The controllers, the authors' noise models and the statistics of the real LiDAR runs are
research data under their own licences; percver reads them where they are and never ships
them. ``data_dir`` finds them: an explicit path, else ``$PERCVER_F1TENTH_DATA``, else a
``f1tenth`` folder in ``$PERCVER_SHARED``, else a ``shared/data/f1tenth`` folder beside or above
the working directory or this package.
"""

from __future__ import annotations

import os
import pickle
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from percver.errors import MissingFileError, ParseError

ENV = "PERCVER_F1TENTH_DATA"
_MARKER = "controllers"


def data_dir(path=None) -> Path:
    """The folder holding ``controllers/``, ``noise_models/``, ``real_data_derived/``."""
    if path is not None:
        folder = Path(path)
        if not (folder / _MARKER).is_dir():
            raise MissingFileError(f"'{folder}' has no '{_MARKER}/' folder: pass the F1/10 data folder (e.g. ../shared/data/f1tenth)")
        return folder
    if os.environ.get(ENV):
        return data_dir(os.environ[ENV])
    shared = os.environ.get("PERCVER_SHARED")
    if shared:
        for candidate in (Path(shared) / "f1tenth", Path(shared) / "data" / "f1tenth"):
            if (candidate / _MARKER).is_dir():
                return candidate
        raise MissingFileError(
            f"$PERCVER_SHARED is '{shared}', which has no f1tenth/{_MARKER}/ folder: point it to the "
            f"shared data folder (../shared/data beside the repository) or set ${ENV}"
        )
    for start in (Path.cwd(), Path(__file__).resolve()):
        for folder in (start, *start.parents):
            for candidate in (folder / "shared" / "data" / "f1tenth", folder.parent / "shared" / "data" / "f1tenth"):
                if (candidate / _MARKER).is_dir():
                    return candidate
    raise MissingFileError(
        f"cannot find the F1/10 data (the authors' controllers, noise models, real-data statistics; not part of "
        f"the percver package): the project keeps it read-only beside the repository as ../shared/data/f1tenth; "
        f"set PERCVER_SHARED=/path/to/shared/data or ${ENV} to the folder, or pass data=... (CLI: --data PATH)"
    )


def _file(data, *parts) -> Path:
    path = data_dir(data).joinpath(*parts)
    if not path.is_file():
        raise MissingFileError(f"'{path}' does not exist: the F1/10 data folder is incomplete")
    return path


def _pickle(path: Path):
    try:
        with open(path, "rb") as f:
            return pickle.load(f, encoding="latin1")  # Python-2 pickles
    except (OSError, pickle.UnpicklingError, EOFError) as error:
        raise ParseError(f"cannot read '{path}' as a pickle: {error}") from None


@dataclass(frozen=True)
class RealStatistics:
    """What is known of the real runs (REFERENCE.md, ``real_data_derived/``).

    ``reflected``: reflected rays per 21-ray scan (one count per sampled scan); ``errors``:
    absolute model errors (m) of the other rays of those scans; both for the environment with
    the reflective surfaces uncovered (the runs) and covered. ``crashes``: 0/1 per run, by the
    short controller name (``DDPG_64_1`` ...). ``outputs``: the 12 controllers' raw outputs on
    every real 21-ray scan (12 x 25,042, rows in ``controllers.NAMES`` order).
    """

    reflected: dict
    errors: dict
    crashes: dict
    outputs: np.ndarray

    @property
    def runs(self) -> int:
        return sum(len(v) for v in self.crashes.values())

    @property
    def crash_count(self) -> int:
        return sum(sum(v) for v in self.crashes.values())

    def summary(self) -> dict:
        out = {"runs": self.runs, "crashes": self.crash_count}
        for env in ("uncovered", "covered"):
            errors = np.asarray(self.errors[env])
            out[env] = {
                "reflected_per_scan": float(np.mean(self.reflected[env])),
                "mean_error_m": float(errors.mean()),
                "within_5cm": float(np.mean(errors <= 0.05)),
            }
        return out


def real_statistics(data=None) -> RealStatistics:
    import yaml

    folder = ("real_data_derived",)
    reflected = {env: np.asarray(_pickle(_file(data, *folder, f"reflected_{env}.pickle")), dtype=float) for env in ("uncovered", "covered")}
    errors = {env: np.asarray(_pickle(_file(data, *folder, f"errors_{env}.pickle")), dtype=float) for env in ("uncovered", "covered")}
    path = _file(data, *folder, "crashes_by_controller.yml")
    try:
        crashes = {str(k): [int(x) for x in v] for k, v in yaml.safe_load(path.read_text()).items()}
    except (yaml.YAMLError, AttributeError, TypeError, ValueError) as error:
        raise ParseError(f"'{path}': expected a mapping from controller to a list of 0/1 crash flags ({error})") from None
    outputs = np.load(_file(data, *folder, "ControllerOuputsOnRealData.npy"))
    return RealStatistics(reflected, errors, crashes, outputs)


def authors_noise_model(data=None, size: str = "5x100") -> tuple[Path, Path]:
    """Paths of the paper's knock-out classifier and its per-ray thresholds."""
    return _file(data, "noise_models", f"noiser{size}.yml"), _file(data, "noise_models", f"thresholds{size}.npy")


def authors_denoiser(data=None) -> Path:
    return _file(data, "noise_models", "denoiser.yml")


def controller_file(name: str, data=None) -> Path:
    return _file(data, "controllers", f"{name}.yml")
