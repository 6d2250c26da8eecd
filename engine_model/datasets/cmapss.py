"""The C-MAPSS (2008) text data sets read into the hyprog table, with N-CMAPSS names.

Files (NASA Prognostics Data Repository, "Turbofan Engine Degradation Simulation Data Set",
subsets FD001-FD004): ``train_FD00x.txt`` (run-to-failure trajectories), ``test_FD00x.txt``
(trajectories cut off some time before failure) and ``RUL_FD00x.txt`` (the true remaining
useful life of each test unit at its last cycle).

Layout of ``train``/``test``: one line per cycle, 26 whitespace-separated numbers (trailing
spaces are common and blank lines are skipped): unit, cycle, three operational settings, 21
sensors. ``RUL``: one number per line, line ``k`` for the ``k``-th test unit in increasing
unit order (units 1..N in the published files).

Column mapping (Saxena, Goebel, Simon & Eklund, "Damage propagation modeling for aircraft
engine run-to-failure simulation", PHM 2008, Table 2; the sensor order checked against the
same table reprinted in Int. J. Aerospace Eng. 2021, article 5876299, Table 3):

=============  ===========================================================================
C-MAPSS        hyprog column [unit]
=============  ===========================================================================
setting 1      ``alt`` [ft]: C-MAPSS gives altitude in kft, multiplied by ``FT_PER_KFT``
setting 2      ``Mach`` [-]
setting 3      ``TRA`` [%] (throttle-resolver angle)
sensors 1-21   ``T2 T24 T30 T50`` [degR], ``P2 P15 P30`` [psia], ``Nf Nc`` [rpm], ``epr`` [-],
               ``Ps30`` [psia], ``phi`` [pps/psi] (fuel flow / Ps30), ``NRf NRc`` [rpm],
               ``BPR`` [-], ``farB`` [-], ``htBleed`` [-], ``Nf_dmd`` [rpm], ``PCNfR_dmd``
               [%], ``W31 W32`` [lbm/s]
=============  ===========================================================================

Quirks of the real files, accepted as they are: lines end in two spaces, copies may have CRLF
line endings, and the operational settings carry noise (FD001 and FD003: altitude about
+-0.009 kft and Mach about +-0.0007 around sea-level static, so some rows read a slightly
negative Mach; FD002: +-0.008 kft, +-0.002 Mach around its six conditions; none on TRA).

- **Settings snapped to the flight envelope.** A setting outside the model's flight envelope
  (:data:`engine_model.validation.ENVELOPE`: altitude -1,500 to 45,000 ft, Mach 0 to 0.9, TRA
  15 to 105 %) by at most :data:`SNAP_TOLERANCE` (100 ft, 0.01 Mach, 1 % TRA: about ten
  times the largest setting noise of the public files) is set to the envelope's bound; one
  further out is an error naming the file, line, column and value. How many rows of each file
  were moved, and by how much at most, is recorded (``settings_snapped``).
- **Operating condition** (column ``condition``, int64): the index, 1 to 6, of the C-MAPSS
  operating condition a row was flown at, :data:`OPERATING_CONDITIONS` (the six regimes of
  FD002 / FD004, Saxena et al. 2008; FD001 and FD003 fly condition 1, sea-level static at TRA
  100): the one whose altitude, Mach and TRA are all within :data:`CONDITION_TOLERANCE`
  (0.5 kft, 0.02, 1 %) of the row's settings; 0 when none is (a file that is not C-MAPSS's).
  The conditions are far apart (no two are closer than 5 kft), so a row is within the
  tolerance of at most one. Rows per condition are recorded (``conditions``).
- **Constant channels**: the sensors that hold one value over every row of the train file
  (FD001: ``T2 P2 epr farB Nf_dmd PCNfR_dmd``), and per condition, are recorded
  (``constant_channels``, ``constant_channels_by_condition``); a model can learn nothing from
  them.

Bookkeeping added: ``t`` = 0.0 (one sample per cycle: a cycle is one snapshot, so there is no
time within a flight and no sample rate; ``sample_rate_hz`` is not recorded) and ``RUL``
[cycles]: for a train unit ``last cycle - cycle``; for a test unit ``RUL_file[unit] + last
cycle - cycle`` (the trajectory stops ``RUL_file[unit]`` cycles before failure). There is no
``Fc``, ``hs`` or health parameter in C-MAPSS.

Units: train units keep their numbers; test unit ``u`` becomes ``offset + u`` so that both
splits live in one table, where ``offset`` (``test_unit_offset`` in the metadata) is the
smallest multiple of ``TEST_UNIT_STEP`` (1000) above every train unit: 1000 for every
published subset, so test unit 7 of FD002 is unit 1007.

Metadata: ``source_format = "cmapss-text"``, ``dev_units`` (the train units), ``test_units``
(renumbered), ``test_unit_offset``, ``source_files`` (``{"train", "test", "rul"}`` file
names), ``cmapss_subset`` (``"FD002"``, when the train file's name says), ``not_physical``,
``settings_snapped``, ``conditions``, ``constant_channels`` and
``constant_channels_by_condition`` (above).
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from ..units import FT_PER_KFT
from ..validation import ENVELOPE, InputError
from .paths import existing_path
from .schema import MAX_FLOAT_ID, canonical_columns

CMAPSS_SOURCE = "cmapss-text"
CMAPSS_SETTINGS = ("alt", "Mach", "TRA")
CMAPSS_SENSORS = (
    "T2", "T24", "T30", "T50", "P2", "P15", "P30", "Nf", "Nc", "epr", "Ps30", "phi", "NRf",
    "NRc", "BPR", "farB", "htBleed", "Nf_dmd", "PCNfR_dmd", "W31", "W32",
)
CMAPSS_COLUMNS = ("unit", "cycle", *CMAPSS_SETTINGS, *CMAPSS_SENSORS)  # the 26 of a line
TEST_UNIT_STEP = 1000
_SUBSET = re.compile(r"FD\d{3}", re.IGNORECASE)

#: The six operating conditions of C-MAPSS FD002 / FD004 as (altitude [kft], Mach, TRA [%]),
#: ``condition`` 1 to 6 in this order (the settings' cluster centres, as in
#: ``data_samples/cmapss-fd002-operating-points.csv``); FD001 / FD003 fly the first.
OPERATING_CONDITIONS = ((0.0, 0.0, 100.0), (10.0, 0.25, 100.0), (20.0, 0.70, 100.0),
                        (25.0, 0.62, 60.0), (35.0, 0.84, 100.0), (42.0, 0.84, 100.0))
#: a row is at a condition when each of its settings is this close to the condition's
#: (altitude [kft], Mach, TRA [%]): some 50 times the settings' noise, a tenth of the
#: smallest distance between two conditions
CONDITION_TOLERANCE = (0.5, 0.02, 1.0)
#: how far outside the flight envelope a setting may read and still be snapped to it
#: (altitude [ft], Mach, TRA [%]): about ten times the largest noise of the public files
SNAP_TOLERANCE = {"alt": 100.0, "Mach": 0.01, "TRA": 1.0}
_ENVELOPE_RANGE = {"alt": ENVELOPE.alt_ft, "Mach": ENVELOPE.Mach, "TRA": ENVELOPE.TRA}


#: C-MAPSS channels that do not follow their stated definition, so that no physics-based
#: model can match them; recorded in the metadata as ``not_physical`` and left out of the
#: default sensor set of a calibration (``CalibrationSetup.exclude_sensors``). C-MAPSS's
#: ``Ps30`` ("HPC outlet static pressure", psia) is about 1/12 of its total ``P30`` at every
#: operating point (47.5 against 554 psia at sea-level take-off in FD001), which no static
#: pressure behind a compressor can be; see README, "Model versus C-MAPSS".
NOT_PHYSICAL = {"Ps30": "about 1/12 of P30 at every point: not a static pressure in psia"}


def _lines(path: Path) -> list[tuple[int, list[str]]]:
    """(1-based line number, tokens) of every non-blank line of a text file. Lines end at
    ``\n`` only (a ``\r`` before it, as in CRLF or ``\r\r\n`` copies, is whitespace), so
    the numbers are those an editor shows."""
    try:
        text = path.read_bytes().decode("ascii")  # no newline translation: \r stays
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not a C-MAPSS text file (byte {exc.start} is not ASCII)"
                         ) from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a directory, expected a C-MAPSS text file") from None
    return [(n, line.split()) for n, line in enumerate(text.split("\n"), 1) if line.strip()]


def _numbers(path: Path, rows: list[tuple[int, list[str]]],
             names: Sequence[str]) -> np.ndarray:
    """The tokens of ``rows`` as a float array (len(rows), len(names)); an InputError names
    the line and column of the first token that is not a finite number."""
    flat = [tok for _, tokens in rows for tok in tokens]
    try:
        values = np.array(flat, dtype=np.float64)
    except ValueError:
        values = pd.to_numeric(pd.Series(flat, dtype=object), errors="coerce").to_numpy(
            dtype=np.float64)
    bad = ~np.isfinite(values)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        line, name, token = rows[i // len(names)][0], names[i % len(names)], flat[i]
        try:
            what = f"value is {float(token)} (NaN or infinite)"
        except ValueError:
            what = f"{token!r} is not a number"
        raise InputError(f"{path}: line {line}, column {name}: {what}")
    return values.reshape(len(rows), len(names))


def _check_integers(path: Path, rows: list[tuple[int, list[str]]], values: np.ndarray,
                    names: Sequence[str], minimum: int) -> None:
    """Each column of ``values`` holds integers from ``minimum`` to 2**53 - 1
    (:data:`~.schema.MAX_FLOAT_ID`: beyond it a float is not exact, and int64 is near); an
    InputError names the line, column and token of the first that does not."""
    for j, name in enumerate(names):
        col = values[:, j]
        bad = (col != np.round(col)) | (col < minimum) | (col > MAX_FLOAT_ID)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise InputError(f"{path}: line {rows[i][0]}, column {name}: {rows[i][1][j]} is"
                             f" not an integer from {minimum} to 2**53 - 1")


def read_cmapss_text(path: str | os.PathLike) -> pd.DataFrame:
    """One ``train_FD00x.txt`` / ``test_FD00x.txt`` file as a table in file order: ``unit``
    and ``cycle`` (int64), ``alt`` [ft], ``Mach``, ``TRA`` (snapped to the flight envelope,
    what moved in ``df.attrs["settings_snapped"]``), ``condition`` (int64) and the 21
    sensors (module doc).
    Raises InputError naming the file, line and column of a line with the wrong number of
    columns, a token that is not a number, a NaN, a unit / cycle that is not an integer from 1
    to 2**53 - 1, a unit whose rows are not together or whose cycles do not follow one
    another (:func:`_check_order`), a setting outside the flight envelope by more than its
    noise or a sensor reading that is not positive, and for a file without data lines."""
    p = existing_path(path)
    rows = _lines(p)
    if not rows:
        raise InputError(f"{p}: no data lines (expected {len(CMAPSS_COLUMNS)} numbers a line)")
    for line, tokens in rows:
        if len(tokens) != len(CMAPSS_COLUMNS):
            raise InputError(f"{p}: line {line}: {len(tokens)} columns, expected"
                             f" {len(CMAPSS_COLUMNS)} (unit, cycle, 3 settings, 21 sensors)")
    values = _numbers(p, rows, CMAPSS_COLUMNS)
    _check_integers(p, rows, values[:, :2], CMAPSS_COLUMNS[:2], minimum=1)
    sensors = values[:, len(CMAPSS_COLUMNS) - len(CMAPSS_SENSORS):]
    bad = np.argwhere(sensors <= 0)
    if len(bad):  # every sensor reads a positive quantity (°R, psia, rpm, ratios, flows)
        i, j = (int(v) for v in bad[0])
        raise InputError(f"{p}: line {rows[i][0]}, column {CMAPSS_SENSORS[j]}: "
                         f"{sensors[i, j]:g} is not positive (every C-MAPSS sensor reads a "
                         "positive quantity)")
    _check_order(p, [line for line, _ in rows], values[:, 0].astype(np.int64),
                 values[:, 1].astype(np.int64))
    df = pd.DataFrame(values, columns=list(CMAPSS_COLUMNS))
    df["unit"] = df["unit"].astype(np.int64)
    df["cycle"] = df["cycle"].astype(np.int64)
    df["alt"] = df["alt"] * FT_PER_KFT
    df.attrs["settings_snapped"] = snap_settings(df, p, [line for line, _ in rows])
    df.insert(5, "condition", operating_condition(df))
    return df


def snap_settings(df: pd.DataFrame, path: Path, lines: Sequence[int]) -> dict[str, dict]:
    """Snap ``df``'s settings (in place; ``alt`` in ft) to the flight envelope where they
    are outside it by at most :data:`SNAP_TOLERANCE` (module docstring) -> per moved setting
    ``{"rows": n, "max_shift": largest move}``. A setting further out is an InputError
    naming ``path``, the line (``lines[i]`` of row ``i``), the column and the value."""
    report = {}
    for name in CMAPSS_SETTINGS:
        lo, hi = _ENVELOPE_RANGE[name]
        col = df[name].to_numpy()
        tol = SNAP_TOLERANCE[name]
        far = (col < lo - tol) | (col > hi + tol)
        if far.any():
            i = int(np.flatnonzero(far)[0])
            shown = col[i] / FT_PER_KFT if name == "alt" else col[i]
            unit = " kft" if name == "alt" else ""
            raise InputError(f"{path}: line {lines[i]}, column {name}: {shown:g}{unit} is"
                             f" outside the flight envelope [{lo:g}, {hi:g}]"
                             f"{' ft' if name == 'alt' else ''} by more than the"
                             f" {tol:g} that setting noise explains")
        snapped = np.clip(col, lo, hi)
        moved = snapped != col
        if moved.any():
            df[name] = snapped
            report[name] = {"rows": int(moved.sum()),
                            "max_shift": float(np.abs(snapped - col).max())}
    return report


def operating_condition(df: pd.DataFrame) -> np.ndarray:
    """The C-MAPSS operating condition of every row (module docstring): 1 to 6, or 0 when the
    settings are at none of :data:`OPERATING_CONDITIONS` (``alt`` in ft)."""
    settings = np.column_stack([df["alt"].to_numpy() / FT_PER_KFT, df["Mach"].to_numpy(),
                                df["TRA"].to_numpy()])
    centres = np.asarray(OPERATING_CONDITIONS)
    near = (np.abs(settings[:, None, :] - centres[None]) <= CONDITION_TOLERANCE).all(axis=2)
    return np.where(near.any(axis=1), near.argmax(axis=1) + 1, 0).astype(np.int64)


def constant_channels(df: pd.DataFrame) -> list[str]:
    """The sensors of ``df`` that hold a single value over every row."""
    return [s for s in CMAPSS_SENSORS if s in df.columns and df[s].nunique() <= 1]


def read_rul_file(path: str | os.PathLike) -> np.ndarray:
    """``RUL_FD00x.txt``: the true RUL [cycles] of each test unit at its last cycle, one
    non-negative integer a line, as int64 in file order. Refused, naming the line: a line of
    more than one number, a token that is not a number, a fraction, a negative value or one
    above 2**53 - 1."""
    p = existing_path(path)
    rows = _lines(p)
    if not rows:
        raise InputError(f"{p}: no data lines (expected one RUL a line)")
    for line, tokens in rows:
        if len(tokens) != 1:
            raise InputError(f"{p}: line {line}: {len(tokens)} columns, expected 1 (RUL)")
    values = _numbers(p, rows, ("RUL",))
    _check_integers(p, rows, values, ("RUL",), minimum=0)
    return values[:, 0].astype(np.int64)


def _rul_to_failure(df: pd.DataFrame, rul_at_end: pd.Series | None = None) -> np.ndarray:
    """RUL of every row: last cycle of its unit - cycle (+ the unit's RUL at its last cycle)."""
    last = df.groupby("unit")["cycle"].transform("max").to_numpy()
    rul = last - df["cycle"].to_numpy()
    if rul_at_end is not None:
        rul = rul + df["unit"].map(rul_at_end).to_numpy()
    return rul.astype(np.int64)


def _check_order(path: Path, lines: Sequence[int], unit: np.ndarray, cycle: np.ndarray
                 ) -> None:
    """The layout of NASA's files: a unit's rows together, one row per cycle, in order
    (cycle ``c + 1`` after cycle ``c``). A unit that comes back after another unit, a cycle
    repeated, going back or skipping cycles would give wrong RUL labels (counted back from a
    unit's last cycle) without a word: refused, naming the line."""
    new_block = np.r_[True, unit[1:] != unit[:-1]]
    seen: dict[int, int] = {}
    for i in np.flatnonzero(new_block):
        u = int(unit[i])
        if u in seen:
            raise InputError(f"{path}: line {lines[i]}: unit {u} again, after other units (its "
                             f"rows began at line {lines[seen[u]]}); a unit's rows must be "
                             "together")
        seen[u] = int(i)
    step = np.diff(cycle)
    bad = np.flatnonzero(~new_block[1:] & (step != 1))
    if len(bad):
        i = int(bad[0]) + 1
        c, before = int(cycle[i]), int(cycle[i - 1])
        what = (f"cycle {c} appears twice (line {lines[i - 1]} too)" if c == before else
                f"cycle {c} after cycle {before} (cycles must increase by one)")
        raise InputError(f"{path}: line {lines[i]}, unit {int(unit[i])}: {what}")


def offset_for_test_units(train_units: Sequence[int]) -> int:
    """The number added to every test unit: the smallest multiple of ``TEST_UNIT_STEP``
    greater than every train unit (1000 for every published subset)."""
    top = max((int(u) for u in train_units), default=0)
    return TEST_UNIT_STEP * (top // TEST_UNIT_STEP + 1)


def read_cmapss(train: str | os.PathLike, test: str | os.PathLike | None = None,
                rul: str | os.PathLike | None = None) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Read a C-MAPSS subset: the train file and, optionally, the test file with its RUL
    file (both or neither) -> ``(df, metadata)`` in the hyprog schema (module doc), sorted by
    unit and cycle. Train units are ``dev_units``; test units, renumbered to
    ``test_unit_offset + unit``, are ``test_units``."""
    if (test is None) != (rul is None):
        given, missing = ("test", "RUL") if rul is None else ("RUL", "test")
        raise InputError(f"{test if rul is None else rul}: a C-MAPSS {given} file needs its"
                         f" {missing} file")
    train_path = existing_path(train)
    dev = read_cmapss_text(train_path)
    dev.insert(2, "RUL", _rul_to_failure(dev))
    frames = [dev]
    offset = offset_for_test_units(dev["unit"].unique())
    files = {"train": train_path.name}
    snapped = {"train": dev.attrs["settings_snapped"]}
    test_units: list[int] = []
    if test is not None:
        test_path, rul_path = existing_path(test), existing_path(rul)
        tst = read_cmapss_text(test_path)
        at_end = read_rul_file(rul_path)
        units = np.sort(tst["unit"].unique())
        if len(at_end) != len(units):
            raise InputError(f"{rul_path}: {len(at_end)} RUL values, but {test_path.name} has"
                             f" {len(units)} test units (one value a unit, in unit order)")
        tst.insert(2, "RUL", _rul_to_failure(tst, pd.Series(at_end, index=units)))
        tst["unit"] = tst["unit"] + offset
        test_units = [int(u) for u in units + offset]
        frames.append(tst)
        files.update(test=test_path.name, rul=rul_path.name)
        snapped["test"] = tst.attrs["settings_snapped"]
    df = pd.concat(frames, ignore_index=True)
    df.insert(2, "t", 0.0)
    df = df.sort_values(["unit", "cycle"], kind="stable", ignore_index=True)
    df = df[canonical_columns(df.columns)]
    counts = df["condition"].value_counts()
    meta: dict[str, Any] = {
        "source_format": CMAPSS_SOURCE,
        "dev_units": sorted(int(u) for u in dev["unit"].unique()),
        "test_units": test_units,
        "test_unit_offset": offset,
        "source_files": files,
        "not_physical": NOT_PHYSICAL,
        "settings_snapped": snapped,
        "conditions": {"centres": [list(c) for c in OPERATING_CONDITIONS],
                       "tolerance": list(CONDITION_TOLERANCE),
                       "rows": {str(int(k)): int(counts[k]) for k in sorted(counts.index)}},
        "constant_channels": constant_channels(dev),
        "constant_channels_by_condition": {
            str(int(k)): constant_channels(g) for k, g in dev.groupby("condition")},
    }
    subset = _SUBSET.search(train_path.name)
    if subset:
        meta["cmapss_subset"] = subset.group(0).upper()
    return df, meta
