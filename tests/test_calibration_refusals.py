"""The calibration library's refusals, each a one-line :class:`InputError` naming what is
wrong (the CLI's are in test_cli_refusals.py): a setup that cannot be run, a unit that
cannot be read, a fleet table without its keys or with a bad label."""

from __future__ import annotations

import numpy as np
import pytest

from calibration import CalibrationSetup, calibrate
from calibration.crb import posterior_crb
from calibration.series import prepare_unit
from engine_model import datasets
from engine_model.validation import InputError
from tests.conftest import REPO


@pytest.fixture(scope="module")
def unit():
    df, _ = datasets.read_dataset(REPO / "data_samples" / "tiny", units=[1])
    return df[df["cycle"] <= 2].reset_index(drop=True)


@pytest.mark.parametrize("kw, message", [
    ({"bounds": (0.1, -0.1)}, "bounds: lower 0.1 must be below upper -0.1"),
    ({"unobservable": "ignore"}, "unobservable policy must be 'exclude' or 'raise', got"
                                 " 'ignore'"),
    ({"sensors": ()}, "calibration: no sensor to use"),
    ({"drift_per": "flight"}, "drift_per must be 'auto', 'cycle' or 'time', got 'flight'"),
])
def test_a_setup_that_cannot_run_is_refused(kw, message):
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        CalibrationSetup(**kw)


def test_a_unit_that_cannot_be_read_names_file_unit_row_and_column(unit):
    bad = unit.copy()
    bad.loc[7, "t"] = np.nan
    with pytest.raises(InputError, match="x.pq, unit 1: row 7, column t: value is nan"):
        prepare_unit(bad, CalibrationSetup(), source="x.pq")
    one = unit[unit["cycle"] == 1].drop(columns="cycle")
    with pytest.raises(InputError, match="unit 1: drift per cycle needs a 'cycle' column"):
        prepare_unit(one, CalibrationSetup(drift_per="cycle"))


def test_a_fleet_table_without_keys_or_with_a_bad_label(unit):
    with pytest.raises(InputError, match="a 'unit' column is needed to calibrate a fleet"):
        calibrate(unit.drop(columns="unit"))
    with pytest.raises(InputError, match="jobs must be >= 1, got 0"):
        calibrate(unit, jobs=0)
    labelled = unit.assign(RUL=5.0)
    labelled.loc[3, "RUL"] = -1.0
    with pytest.raises(InputError, match=r"unit 1, row 4: column RUL = -1 \(the remaining"
                                         r" useful life must be a finite number >= 0\)"):
        calibrate(labelled)


def test_the_bound_refuses_steps_that_do_not_match_the_samples():
    with pytest.raises(ValueError, match="q_var: expected 4 values, got 3"):
        posterior_crb(np.ones((4, 2, 2)), np.ones(3), np.eye(2))
