"""Output files of the prognostics and of the commands above it: text, JSON, tables, and
``predict``'s two prediction tables.

Every file is written through :func:`engine_model.runtime.atomic.atomic_output` (the one
atomic writer): built as a hidden temporary sibling and moved into place only after writing
succeeded, so a reader never sees half a file and an error leaves the old file alone; what a
killed writer left is deleted by the next one.

Whose file may be replaced is the ownership rule (:mod:`engine_model.runtime.ownership`). The
plain writers (:func:`write_text`, :func:`write_json`, :func:`write_table`,
:func:`write_bytes`) write by default inside an output folder the command already owns (kind
:data:`~engine_model.runtime.ownership.OWNED_FILE`: a run's record, a stage's marker, a
figure). :func:`write_predictions` writes a user's ``--out`` and its sidecar
``<stem>.per_cycle<suffix>`` (:func:`per_cycle_path`), each checked as an output of its own:
an earlier prediction table is recognised by its columns (the CSV header or the parquet
schema: exactly those ``predict`` writes, :data:`PREDICTION_COLUMNS` and
:data:`PER_CYCLE_COLUMNS`); anything else is replaced only with ``--overwrite``, a special
file or an input of the command never. The two files are swapped in together: both new, or
both as they were.
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from pathlib import Path

import pandas as pd

from engine_model.datasets.jsonable import json_default
from engine_model.runtime.atomic import atomic_output, atomic_outputs
from engine_model.runtime.ownership import OWNED_FILE, OutputKind
from engine_model.validation import InputError

#: Columns of ``predict``'s per-sample table (those after ``cycle`` when the data have them).
PREDICTION_COLUMNS = ("unit", "cycle", "t", "RUL", "hs", "RUL_pred", "RUL_std", "RUL_lower",
                      "RUL_upper")
#: Columns of ``predict``'s per-cycle table (:func:`prognostics.metrics.per_cycle`).
PER_CYCLE_COLUMNS = ("unit", "cycle", "RUL", "mean", "min", "max", "n", "lower", "upper")
HEADER_BYTES = 1 << 16


def write_text(path: str | os.PathLike, text: str, kind: OutputKind = OWNED_FILE) -> Path:
    with atomic_output(path, kind) as tmp:
        tmp.write_text(text)
    return Path(path)


def write_bytes(path: str | os.PathLike, data: bytes, kind: OutputKind = OWNED_FILE) -> Path:
    with atomic_output(path, kind) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_json(path: str | os.PathLike, obj, kind: OutputKind = OWNED_FILE) -> Path:
    return write_text(path, json.dumps(obj, indent=1, allow_nan=False, default=json_default)
                      + "\n", kind)


def _to_table_file(tmp: Path, df: pd.DataFrame, target: Path) -> None:
    """CSV when ``target`` ends in ``.csv``, parquet (one file) otherwise."""
    if target.suffix.lower() == ".csv":
        df.to_csv(tmp, index=False)
    else:
        df.to_parquet(tmp, index=False)


def write_table(path: str | os.PathLike, df: pd.DataFrame,
                kind: OutputKind = OWNED_FILE) -> Path:
    """CSV for ``.csv``, parquet (one file) otherwise."""
    p = Path(path)
    with atomic_output(p, kind) as tmp:
        _to_table_file(tmp, df, p)
    return p


def table_columns(path: Path) -> list[str] | None:
    """The column names of a parquet file (its schema) or of a CSV file (its header line),
    None when ``path`` is neither."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(HEADER_BYTES)
    except OSError:
        return None
    if head.startswith(b"PAR1"):
        import pyarrow as pa
        import pyarrow.parquet as pq

        try:
            return list(pq.read_schema(path).names)
        except (pa.ArrowException, OSError):
            return None
    line = head.split(b"\n", 1)[0].rstrip(b"\r")
    try:
        return line.decode("utf-8").split(",") if line else None
    except UnicodeDecodeError:
        return None


def _has_columns(required: set[str], allowed: Sequence[str]):
    def recognise(path: Path) -> bool:
        cols = table_columns(path)
        return cols is not None and required <= set(cols) and set(cols) <= set(allowed) \
            and len(cols) == len(set(cols))

    return recognise


#: ``predict``'s per-sample table (module docstring).
PREDICTIONS = OutputKind("a hyprog prediction table", directory=False,
                         ours=_has_columns({"unit", "cycle", "RUL_pred"}, PREDICTION_COLUMNS))
#: ``predict``'s per-cycle table (module docstring).
PER_CYCLE = OutputKind("a hyprog per-cycle prediction table", directory=False,
                       ours=_has_columns({"unit", "cycle", "mean", "min", "max", "n"},
                                         PER_CYCLE_COLUMNS))


def per_cycle_path(out: str | os.PathLike) -> Path:
    """``preds.csv`` -> ``preds.per_cycle.csv`` (same format as ``out``)."""
    out = Path(out)
    if not out.name:
        raise InputError(f"--out {str(out)!r}: a file name is needed (e.g. rul.csv)")
    return out.with_name(f"{out.stem}.per_cycle{out.suffix}")


#: The suffixes of a prediction table: CSV, else parquet (a name without a suffix too).
TABLE_SUFFIXES = (".csv", ".parquet", ".pq", "")


def check_table_suffix(out: str | os.PathLike) -> None:
    """A suffix that names another format (``.h5``, ``.txt``) is refused rather than given a
    parquet file under that name."""
    suffix = Path(out).suffix.lower()
    if suffix not in TABLE_SUFFIXES:
        raise InputError(f"--out {out}: a prediction table is written as CSV (.csv) or "
                         f"parquet (.parquet, .pq), not {suffix}")


def prediction_targets(out: str | os.PathLike) -> list[tuple[Path, OutputKind]]:
    """``predict``'s outputs and their kinds: ``out`` and its per-cycle sidecar."""
    return [(Path(out), PREDICTIONS), (per_cycle_path(out), PER_CYCLE)]


def write_predictions(pred: pd.DataFrame, per_cycle: pd.DataFrame, out: str | os.PathLike,
                      overwrite: bool = False, inputs: Sequence = ()) -> tuple[Path, Path]:
    """Write the per-sample table to ``out`` and the per-cycle one beside it (module
    docstring); returns both paths."""
    targets = prediction_targets(out)
    with atomic_outputs(targets, overwrite, inputs) as tmps:
        for tmp, (target, _), df in zip(tmps, targets, (pred, per_cycle), strict=True):
            _to_table_file(tmp, df, target)
    return targets[0][0], targets[1][0]
