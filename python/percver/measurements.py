"""Measured data that a model is compared with: states, sensor readings, controls, trajectories.

A ``Measurements`` object is checked once, when it is built, so that everything downstream
(comparison, fitting, reports) can trust its shapes, names and values. Every refusal is a
``MeasurementError`` naming the field, the offending rows and the fix.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from percver.errors import MeasurementError

# The array fields in file order; ``names`` and ``meta`` travel as JSON text next to them.
_ARRAYS = ("states", "measurements", "controls", "next_states", "trajectory", "time")
_NAMED = {"states": "state", "measurements": "measurement", "controls": "control", "next_states": "next_state"}
_SHOWN_ROWS = 8


def _rows_text(rows: np.ndarray) -> str:
    shown = ", ".join(str(int(r)) for r in rows[:_SHOWN_ROWS])
    more = f" and {len(rows) - _SHOWN_ROWS} more" if len(rows) > _SHOWN_ROWS else ""
    return f"row{'s' if len(rows) > 1 else ''} {shown}{more}"


@dataclass(frozen=True)
class Transitions:
    """One-step pairs (state_k, control_k) -> state_{k+1} taken from measurements.

    ``history[:, j]`` is the control applied ``j`` periods before step k (``history[:, 0]`` is
    ``controls``); at the start of a trajectory the first control is held, since nothing
    earlier was measured. ``has_history`` is False when the data has no trajectories.
    """

    rows: np.ndarray
    states: np.ndarray
    controls: np.ndarray
    next_states: np.ndarray
    history: np.ndarray
    groups: np.ndarray | None
    has_history: bool


class Measurements:
    """States and what was measured in them, with optional controls and trajectories.

    ``states`` is N x n; ``measurements`` N x m (sensor data) and/or the dynamics fields:
    ``controls`` N x p with either ``next_states`` N x n or ``trajectory`` ids plus ``time``
    (consecutive rows of one trajectory form the one-step pairs). ``measurement_names`` may
    be a list of names or a sensor description with a ``names`` attribute (e.g. a ``Lidar``).
    ``dropna=True`` drops rows holding NaN or inf instead of refusing them (the dropped
    original row numbers are kept in ``dropped_rows``). ``source`` names the origin (a file)
    in error messages.
    """

    def __init__(
        self,
        states,
        measurements=None,
        *,
        controls=None,
        next_states=None,
        trajectory=None,
        time=None,
        state_names=None,
        measurement_names=None,
        control_names=None,
        meta=None,
        dropna: bool = False,
        source: str | None = None,
    ):
        self.source = source
        where = f" in {source}" if source else ""
        self.states = self._matrix("states", states, where)
        n_rows = self.states.shape[0]
        self.measurements = None if measurements is None else self._matrix("measurements", measurements, where)
        self.controls = None if controls is None else self._matrix("controls", controls, where)
        self.next_states = None if next_states is None else self._matrix("next_states", next_states, where)
        self.trajectory = None if trajectory is None else self._vector("trajectory", trajectory, where)
        self.time = None if time is None else self._vector("time", time, where)
        for field in _ARRAYS[1:]:
            value = getattr(self, field)
            if value is not None and value.shape[0] != n_rows:
                raise MeasurementError(
                    f"'{field}'{where} has {value.shape[0]} rows but 'states' has {n_rows}: "
                    "every row is one sample, so all arrays need the same number of rows"
                )
        if self.next_states is not None and self.next_states.shape[1] != self.states.shape[1]:
            raise MeasurementError(
                f"'next_states'{where} has {self.next_states.shape[1]} columns but 'states' has "
                f"{self.states.shape[1]}: next_states[i] is the state one period after states[i]"
            )
        if self.trajectory is not None and self.trajectory.dtype.kind == "f":
            if not np.all(np.isfinite(self.trajectory)) or np.any(self.trajectory != np.round(self.trajectory)):
                raise MeasurementError(f"'trajectory'{where} must hold integer ids, one per row")
            self.trajectory = self.trajectory.astype(np.int64)
        if self.trajectory is not None and self.time is None:
            raise MeasurementError(
                f"'trajectory'{where} is given without 'time': give the time of each row so the one-step pairs can be ordered"
            )

        self.state_names = self._names("state", state_names, self.states.shape[1], "x", where)
        self.measurement_names = (
            None if self.measurements is None else self._names("measurement", measurement_names, self.measurements.shape[1], "y", where)
        )
        self.control_names = None if self.controls is None else self._names("control", control_names, self.controls.shape[1], "u", where)
        self.meta = dict(meta or {})
        self.dropped_rows = np.zeros(0, dtype=np.int64)
        self._check_finite(dropna, where)
        self._check_time(where)

    # ------------------------------------------------------------------ construction checks
    @staticmethod
    def _matrix(field, value, where):
        try:
            array = np.asarray(value, dtype=float)
        except (TypeError, ValueError) as error:
            raise MeasurementError(f"'{field}'{where} must be numeric: {error}") from None
        if array.ndim == 1:
            array = array[:, None]
        if array.ndim != 2:
            raise MeasurementError(
                f"'{field}'{where} has shape {array.shape}: give a 2-D array with one row per sample (flatten images to one row each)"
            )
        if array.shape[0] == 0:
            raise MeasurementError(f"'{field}'{where} has no rows")
        return array

    @staticmethod
    def _vector(field, value, where):
        array = np.asarray(value)
        if array.ndim != 1:
            raise MeasurementError(f"'{field}'{where} has shape {array.shape}: give one value per row")
        if array.dtype.kind not in "iuf":
            raise MeasurementError(f"'{field}'{where} must be numeric, got dtype {array.dtype}")
        return array if array.dtype.kind in "iu" else array.astype(float)

    @staticmethod
    def _names(kind, names, count, prefix, where):
        names = getattr(names, "names", names)
        if names is None:
            return tuple(f"{prefix}{i}" for i in range(count))
        names = tuple(str(name) for name in names)
        if len(names) != count:
            raise MeasurementError(f"{len(names)} {kind} names{where} for {count} {kind} columns: give exactly one name per column")
        duplicates = sorted({name for name in names if names.count(name) > 1})
        if duplicates:
            raise MeasurementError(f"{kind} names{where} repeat {duplicates}: names must be unique")
        return names

    def _check_finite(self, dropna, where):
        bad = np.zeros(self.states.shape[0], dtype=bool)
        fields = []
        for field in _ARRAYS:
            value = getattr(self, field)
            if value is None or value.dtype.kind not in "f":
                continue
            finite = np.isfinite(value) if value.ndim == 1 else np.isfinite(value).all(axis=1)
            if not finite.all():
                fields.append(field)
                bad |= ~finite
        if not bad.any():
            return
        rows = np.flatnonzero(bad)
        if not dropna:
            raise MeasurementError(
                f"NaN or inf in {', '.join(repr(f) for f in fields)}{where} at {_rows_text(rows)}: "
                "fix those samples or pass dropna=True to drop them"
            )
        keep = ~bad
        if not keep.any():
            raise MeasurementError(f"every row{where} holds NaN or inf; nothing is left after dropna=True")
        for field in _ARRAYS:
            value = getattr(self, field)
            if value is not None:
                setattr(self, field, value[keep])
        self.dropped_rows = rows

    def _check_time(self, where):
        if self.time is None:
            return
        groups = self.trajectory if self.trajectory is not None else np.zeros(len(self.time), dtype=np.int64)
        same = groups[1:] == groups[:-1]
        not_later = same & (np.diff(self.time) <= 0)
        if not_later.any():
            rows = np.flatnonzero(not_later) + 1
            raise MeasurementError(
                f"'time'{where} does not increase within a trajectory at {_rows_text(rows)}: sort the rows "
                "by (trajectory, time), e.g. order = np.lexsort((time, trajectory)), and drop repeated times"
            )
        # A trajectory split into two blocks would silently become two pairs' sequences.
        starts = groups[np.r_[True, ~same]]
        if len(np.unique(starts)) != len(starts):
            repeated = [int(g) for g in np.unique(starts) if np.sum(starts == g) > 1]
            raise MeasurementError(
                f"trajectory ids {repeated[:_SHOWN_ROWS]}{where} occur in more than one block of rows: keep the "
                "rows of each trajectory together, sorted by time"
            )

    # ------------------------------------------------------------------ access
    def __len__(self) -> int:
        return self.states.shape[0]

    def __repr__(self) -> str:
        parts = [f"{len(self)} rows", f"states {list(self.state_names)}"]
        if self.measurements is not None:
            parts.append(f"{self.measurements.shape[1]} measurements")
        if self.controls is not None:
            parts.append(f"controls {list(self.control_names)}")
        if self.trajectory is not None:
            parts.append(f"{len(np.unique(self.trajectory))} trajectories")
        return f"Measurements({', '.join(parts)})"

    @property
    def groups(self) -> np.ndarray | None:
        """Trajectory id per row, or None when rows are independent samples."""
        return self.trajectory

    def column(self, name: str) -> np.ndarray:
        """The column called ``name`` among states, measurements and controls."""
        for names, values in (
            (self.state_names, self.states),
            (self.measurement_names, self.measurements),
            (self.control_names, self.controls),
        ):
            if names is not None and name in names:
                return values[:, names.index(name)]
        raise MeasurementError(f"unknown column '{name}'{self._where()}; known: {self._known()}")

    def state_index(self, names) -> list:
        """Column numbers of the states ``names`` (a model's state names)."""
        missing = [name for name in names if name not in self.state_names]
        if missing:
            raise MeasurementError(
                f"the model needs state{'s' if len(missing) > 1 else ''} {missing} but the data{self._where()} "
                f"has states {list(self.state_names)}: rename the columns with state_names=..."
            )
        return [self.state_names.index(name) for name in names]

    def state_matrix(self, names) -> np.ndarray:
        """The state columns in the order of ``names``."""
        return self.states[:, self.state_index(names)]

    def select(self, rows) -> "Measurements":
        """A new Measurements holding only ``rows`` (indices or a boolean mask), in order."""
        rows = np.asarray(rows)
        arrays = {field: None if getattr(self, field) is None else getattr(self, field)[rows] for field in _ARRAYS}
        return Measurements(
            arrays.pop("states"),
            arrays.pop("measurements"),
            **arrays,
            state_names=self.state_names,
            measurement_names=self.measurement_names,
            control_names=self.control_names,
            meta=self.meta,
            source=self.source,
        )

    def require(self, count: int, what: str) -> None:
        """Refuse to fit ``count`` parameters from fewer samples than that."""
        if len(self) < count:
            raise MeasurementError(
                f"{what} has {count} parameters to fit but the data{self._where()} has only {len(self)} "
                "samples: measure more samples or fit fewer parameters"
            )

    def transitions(self, history: int = 0) -> Transitions:
        """The one-step pairs for dynamics models, with ``history`` earlier controls per pair."""
        where = self._where()
        if self.controls is None:
            raise MeasurementError(f"dynamics need 'controls'{where}: give the control applied at each row")
        has_history = self.next_states is None and self.time is not None
        if self.next_states is not None:
            rows = np.arange(len(self))
            following = self.next_states
            previous = rows
        elif has_history:
            previous = self._previous_rows()
            rows = np.flatnonzero(previous[1:] == np.arange(len(self) - 1))
            following = self.states[rows + 1]
        else:
            raise MeasurementError(f"dynamics need 'next_states' or 'trajectory' and 'time'{where} to form one-step pairs")
        if len(rows) == 0:
            raise MeasurementError(f"no one-step pairs{where}: every trajectory has a single row")
        lagged = [self.controls[rows]]
        index = rows
        for _ in range(history):
            index = previous[index]
            lagged.append(self.controls[index])
        return Transitions(
            rows=rows,
            states=self.states[rows],
            controls=self.controls[rows],
            next_states=following,
            history=np.stack(lagged, axis=1),
            groups=None if self.trajectory is None else self.trajectory[rows],
            has_history=has_history,
        )

    def _previous_rows(self) -> np.ndarray:
        """Row one period earlier in the same trajectory, or the row itself (a start or a gap).

        The period is the median time step; a longer step (rows dropped by ``dropna``) breaks the
        chain so that no pair spans two periods.
        """
        groups = self.trajectory if self.trajectory is not None else np.zeros(len(self), dtype=np.int64)
        step = np.diff(self.time)
        same = groups[1:] == groups[:-1]
        period = np.median(step[same]) if same.any() else 0.0
        linked = same & (np.abs(step - period) <= 1e-6 * abs(period) + 1e-12)
        previous = np.arange(len(self))
        previous[1:][linked] -= 1
        return previous

    def _where(self) -> str:
        return f" in {self.source}" if self.source else ""

    def _known(self) -> str:
        known = list(self.state_names) + list(self.measurement_names or ()) + list(self.control_names or ())
        return ", ".join(known[:20]) + (" ..." if len(known) > 20 else "")

    # ------------------------------------------------------------------ files
    def _names_json(self) -> str:
        return json.dumps(
            {
                "states": list(self.state_names),
                "measurements": None if self.measurement_names is None else list(self.measurement_names),
                "controls": None if self.control_names is None else list(self.control_names),
            }
        )

    def save(self, path) -> Path:
        """Write ``.npz`` (arrays plus ``names``/``meta`` as JSON text) or ``.parquet``."""
        path = Path(path)
        suffix = path.suffix.lower()
        if suffix == ".npz":
            arrays = {field: getattr(self, field) for field in _ARRAYS if getattr(self, field) is not None}
            np.savez_compressed(path, **arrays, names=np.array(self._names_json()), meta=np.array(json.dumps(self.meta, default=str)))
        elif suffix == ".parquet":
            self._save_parquet(path)
        else:
            raise MeasurementError(f"cannot save measurements as '{path.name}': use a .npz or .parquet file name")
        return path

    @classmethod
    def load(cls, path, *, dropna: bool = False) -> "Measurements":
        """Read a file written by ``save`` (or by hand with the same keys or columns)."""
        path = Path(path)
        if not path.exists():
            raise MeasurementError(f"measurement file '{path}' does not exist")
        suffix = path.suffix.lower()
        if suffix == ".npz":
            return cls._load_npz(path, dropna)
        if suffix == ".parquet":
            return cls._load_parquet(path, dropna)
        raise MeasurementError(f"cannot read measurements from '{path.name}': use a .npz or .parquet file")

    @classmethod
    def _load_npz(cls, path, dropna):
        try:
            with np.load(path, allow_pickle=False) as npz:
                content = {key: npz[key] for key in npz.files}
        except (OSError, ValueError, zipfile.BadZipFile):
            # numpy's own message suggests allow_pickle=True, which would run code from the file.
            raise MeasurementError(
                f"cannot read '{path}': the file is corrupt or not a percver measurement file (an .npz written by "
                "Measurements.save, or np.savez(path, states=..., measurements=...))"
            ) from None
        if "states" not in content:
            raise MeasurementError(
                f"'{path}' has no 'states' array (keys: {sorted(content)}): save with Measurements.save or "
                "np.savez(path, states=..., measurements=...)"
            )
        names = cls._json_field(path, content, "names")
        meta = cls._json_field(path, content, "meta")
        unknown = sorted(set(content) - set(_ARRAYS) - {"names", "meta"})
        if unknown:
            raise MeasurementError(f"'{path}' has unknown arrays {unknown}: the keys are {list(_ARRAYS)}, 'names' and 'meta'")
        arrays = {field: content.get(field) for field in _ARRAYS}
        return cls(
            arrays.pop("states"),
            arrays.pop("measurements"),
            **arrays,
            state_names=names.get("states"),
            measurement_names=names.get("measurements"),
            control_names=names.get("controls"),
            meta=meta,
            dropna=dropna,
            source=str(path),
        )

    @staticmethod
    def _json_field(path, content, key):
        if key not in content:
            return {}
        try:
            value = json.loads(str(content[key]))
        except json.JSONDecodeError as error:
            raise MeasurementError(f"'{key}' in '{path}' is not JSON text: {error}") from None
        if not isinstance(value, dict):
            raise MeasurementError(f"'{key}' in '{path}' must be a JSON object, got {type(value).__name__}")
        return value

    # Parquet keeps one column per named value: "state.<name>", "measurement.<name>",
    # "control.<name>", "next_state.<name>", plus "trajectory" and "time"; meta is schema metadata.
    def _save_parquet(self, path):
        import pyarrow as pa
        import pyarrow.parquet as pq

        columns = {}
        names = {
            "states": self.state_names,
            "measurements": self.measurement_names,
            "controls": self.control_names,
            "next_states": self.state_names,
        }
        for field, prefix in _NAMED.items():
            values = getattr(self, field)
            if values is not None:
                for j, name in enumerate(names[field]):
                    columns[f"{prefix}.{name}"] = values[:, j]
        for field in ("trajectory", "time"):
            if getattr(self, field) is not None:
                columns[field] = getattr(self, field)
        table = pa.table(columns).replace_schema_metadata({"percver.meta": json.dumps(self.meta, default=str)})
        pq.write_table(table, path)

    @classmethod
    def _load_parquet(cls, path, dropna):
        import pyarrow.parquet as pq

        try:
            table = pq.read_table(path)
        except Exception as error:  # pyarrow raises several unrelated types for unreadable files
            raise MeasurementError(f"cannot read '{path}' as parquet: {error}") from None
        groups = {prefix: [] for prefix in _NAMED.values()}
        plain = {}
        for column in table.column_names:
            prefix, dot, name = column.partition(".")
            if dot and prefix in groups:
                groups[prefix].append(name)
            elif column in ("trajectory", "time"):
                plain[column] = table.column(column).to_numpy()
            else:
                raise MeasurementError(
                    f"column '{column}' in '{path}' is not understood: name columns 'state.<name>', "
                    "'measurement.<name>', 'control.<name>', 'next_state.<name>', 'trajectory' or 'time'"
                )
        if not groups["state"]:
            raise MeasurementError(
                f"'{path}' has no 'state.<name>' columns (columns: {table.column_names[:10]}): name state columns 'state.<name>'"
            )

        def stack(prefix):
            names = groups[prefix]
            if not names:
                return None
            return np.column_stack([table.column(f"{prefix}.{name}").to_numpy(zero_copy_only=False) for name in names])

        if groups["next_state"] and groups["next_state"] != groups["state"]:
            raise MeasurementError(
                f"'{path}' has next_state columns {groups['next_state']} but state columns {groups['state']}: "
                "they must name the same variables in the same order"
            )
        metadata = table.schema.metadata or {}
        meta = json.loads(metadata[b"percver.meta"]) if b"percver.meta" in metadata else {}
        return cls(
            stack("state"),
            stack("measurement"),
            controls=stack("control"),
            next_states=stack("next_state"),
            trajectory=plain.get("trajectory"),
            time=plain.get("time"),
            state_names=groups["state"],
            measurement_names=groups["measurement"] or None,
            control_names=groups["control"] or None,
            meta=meta,
            dropna=dropna,
            source=str(path),
        )
