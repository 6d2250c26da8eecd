"""A fleet dataset as one object: the table, its metadata and the split the metadata names.

:func:`~.dispatch.read_dataset` returns a bare ``(DataFrame, dict)``; a library user then
looks up where the development and test units are (the metadata's ``dev_units`` /
``test_units``) and carries the two objects side by side. :class:`Dataset` holds them
together, typed, and is what the library's high-level entry points take and return
(:func:`load_sample`, :func:`calibration.calibrate`, :class:`prognostics.RulEstimator`)::

    from engine_model.datasets import load_sample

    fleet = load_sample()                 # the packaged four-unit fleet
    fleet.units, fleet.dev_units, fleet.test_units  # [1, 2, 3, 4], [1, 2, 3], [4]
    train = fleet.development()           # a Dataset of the development units
    fleet.write("fleet")                  # hyprog parquet, metadata with it

The table is the one of :mod:`.schema` (``unit``, ``cycle``, ``t``, ``w``, ``x_s``, ...);
a feature table (after calibration) is a Dataset too, with the estimates beside the data.
A Dataset never copies its table unless it selects rows.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from ..validation import InputError
from .dispatch import read_dataset, write_dataset


@dataclass(frozen=True)
class Dataset:
    """A fleet table with its metadata (module docstring). ``source`` names it in errors
    (the path it was read from, or ``"table"``)."""

    frame: pd.DataFrame
    metadata: dict[str, Any] = field(default_factory=dict)
    source: str = "table"

    @classmethod
    def read(cls, path: str | os.PathLike, units: Sequence[int] | None = None) -> Dataset:
        """Read hyprog parquet or N-CMAPSS h5 (:func:`~.dispatch.read_dataset`)."""
        frame, metadata = read_dataset(path, units=units)
        return cls(frame, metadata, str(path))

    def __len__(self) -> int:
        return len(self.frame)

    @property
    def units(self) -> list[int]:
        """Every unit of the table, in order."""
        return sorted(int(u) for u in self.frame["unit"].unique()) if len(self) else []

    def _listed(self, key: str) -> list[int]:
        value = self.metadata.get(key) or []
        if not isinstance(value, list | tuple):
            raise InputError(f"{self.source}: metadata {key} must be a list of unit numbers")
        present = set(self.units)
        return [int(u) for u in value if int(u) in present]

    @property
    def dev_units(self) -> list[int]:
        """The metadata's development units present in the table (empty when it names
        none)."""
        return self._listed("dev_units")

    @property
    def test_units(self) -> list[int]:
        """The metadata's test units present in the table (empty when it names none)."""
        return self._listed("test_units")

    def select(self, units: Sequence[int]) -> Dataset:
        """The rows of ``units`` (an error naming any unit the table lacks)."""
        wanted = [int(u) for u in units]
        missing = sorted(set(wanted) - set(self.units))
        if missing:
            raise InputError(f"{self.source}: unit(s) {', '.join(map(str, missing))} not in "
                             "the table")
        rows = self.frame["unit"].isin(wanted)
        return Dataset(self.frame[rows].reset_index(drop=True), self.metadata, self.source)

    def development(self) -> Dataset:
        """The development units (the metadata's ``dev_units``)."""
        if not self.dev_units:
            raise InputError(f"{self.source}: the metadata names no dev_units")
        return self.select(self.dev_units)

    def test(self) -> Dataset:
        """The test units (the metadata's ``test_units``)."""
        if not self.test_units:
            raise InputError(f"{self.source}: the metadata names no test_units")
        return self.select(self.test_units)

    def unit_frames(self) -> list[pd.DataFrame]:
        """One table per unit, in unit order (what :func:`calibration.discrepancy.discover`
        takes)."""
        return [g.reset_index(drop=True) for _, g in self.frame.groupby("unit", sort=True)]

    def to_frame(self) -> pd.DataFrame:
        """The table (not a copy)."""
        return self.frame

    def write(self, path: str | os.PathLike, overwrite: bool = False) -> Path:
        """Write the table and its metadata (:func:`~.dispatch.write_dataset`: parquet, or
        h5 by suffix; an existing ``path`` is replaced only when hyprog wrote it or with
        ``overwrite``)."""
        return write_dataset(self.frame, path, self.metadata, overwrite=overwrite)


def load_sample(name: str = "tiny") -> Dataset:
    """A fleet packaged with hyprog (:mod:`data_samples`) as a :class:`Dataset`: ``"tiny"``,
    four units of the simulator's ``tiny`` preset (1-3 development, 4 test)."""
    from data_samples import sample_path

    return Dataset.read(sample_path(name))
