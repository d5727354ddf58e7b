"""Case studies of the paper: each one a package with its data, models, evaluation and (later) verification."""

from percver.cases import mountain_car

__all__ = ["mountain_car"]
from percver.cases import f1tenth  # noqa: E402

__all__ += ["f1tenth"]
