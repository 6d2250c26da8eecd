"""The model-versus-reference comparison (engine_model.analysis.reference) and the envelope sweep
report (engine_model.analysis.envelope): the table checks and the report arithmetic on a stand-in
model, the known channels and finite errors on the engine model."""

import math

import numpy as np
import pandas as pd
import pytest

from engine_model import THETA_NAMES, W_NAMES
from engine_model.analysis.envelope import envelope_report
from engine_model.analysis.reference import (
    REFERENCE_CHANNELS,
    compare_reference,
    default_reference_path,
    error_table,
    load_reference,
)
from engine_model.analysis.sampling import envelope_points
from engine_model.validation import InputError

HEADER = "alt_kft,Mach,TRA,T2,T30,Nc,Ps30"
ROW = "25.0,0.62,60.0,462.54,1259.8,8009.0,36.6"


class ScaledModel:
    """Stands in for EngineModel.evaluate: every channel = factor * a known value; records
    the operating points it was given; rows in ``fail`` do not converge."""

    def __init__(self, values, factor=1.01, fail=()):
        self.values, self.factor, self.fail, self.seen = values, factor, set(fail), None

    def evaluate(self, w, theta=None):
        self.seen = w.copy()
        out = pd.DataFrame({c: self.factor * v for c, v in self.values.items()}, index=w.index)
        out["converged"] = [i not in self.fail for i in w.index]
        out["residual_norm"] = [1.0 if i in self.fail else 1e-12 for i in w.index]
        return out


def write(tmp_path, *lines, name="ref.csv"):
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n")
    return path


def test_default_table_has_six_points_and_the_fourteen_channels():
    ref = load_reference(default_reference_path())
    assert len(ref) == 6 and list(ref.index) == [1, 2, 3, 4, 5, 6]
    assert list(ref.columns) == ["alt_kft", "Mach", "TRA", "T2", *REFERENCE_CHANNELS]
    assert len(REFERENCE_CHANNELS) == 14 and not {"Ps30", "phi"} & set(ref.columns)


def test_comparison_runs_at_alt_in_feet_and_computes_percent_errors(tmp_path):
    ref = load_reference(write(tmp_path, HEADER, ROW, "0,0,100,518.67,,9055.8,47.3"))
    model = ScaledModel({"T30": 1272.0, "Nc": 8100.0}, factor=1.0, fail={2})
    records = compare_reference(model, ref)
    assert model.seen["alt"].tolist() == [25000.0, 0.0]  # kft -> ft
    assert list(model.seen.columns) == list(W_NAMES)
    first, second = records
    assert first["row"] == 1 and first["converged"] and not second["converged"]
    assert first["T30_err_pct"] == pytest.approx(100 * (1272.0 - 1259.8) / 1259.8)
    assert first["Nc_err_pct"] == pytest.approx(100 * (8100.0 - 8009.0) / 8009.0)
    assert first["max_abs_err_pct"] == pytest.approx(first["Nc_err_pct"])
    assert math.isnan(second["T30_err_pct"])  # the reference cell is empty
    assert second["max_abs_err_pct"] == pytest.approx(abs(second["Nc_err_pct"]))
    assert "Ps30_ref" not in first  # Ps30 is never compared
    table = error_table(records)
    assert list(table.columns) == ["T30", "Nc"]
    assert table.index.tolist() == ["25 kft M0.62 TRA60", "0 kft M0 TRA100"]


@pytest.mark.parametrize("lines, fragments", [
    ((HEADER.replace("Mach", "Speed"), ROW), ("missing column(s) Mach",)),
    ((HEADER, ROW.replace("1259.8", "hot")), ("row 1, column T30", "'hot'")),
    ((HEADER, ROW, ",0.5,80,500,1300,8000,40"), ("row 2, column alt_kft", "missing")),
    ((HEADER, ROW.replace("0.62", "1.5")), ("row 1", "column Mach = 1.5", "envelope")),
    (("alt_kft,Mach,TRA,T2,Ps30", "0,0,100,518.67,47.3"), ("no channel to compare",)),
    ((HEADER,), ("no rows",)),
    (("",), ("cannot read as CSV",)),
])
def test_bad_tables_name_file_row_and_column(tmp_path, lines, fragments):
    path = write(tmp_path, *lines)
    with pytest.raises(InputError) as info:
        load_reference(path)
    message = str(info.value)
    assert message.startswith(str(path)) and "--" not in message  # no CLI flags
    for f in fragments:
        assert f in message, (f, message)
    with pytest.raises(InputError, match="no such file"):
        load_reference(tmp_path / "missing.csv")


def test_envelope_report_counts_failures_and_reports_them():
    pts = envelope_points(20, seed=5)
    model = ScaledModel({"T30": 1.0}, fail={3, 17})
    rep = envelope_report(model, 20, seed=5)
    assert rep["n_points"] == 20 and rep["n_failed"] == 2
    assert rep["convergence_rate"] == pytest.approx(0.9)
    assert [f["row"] for f in rep["failures"]] == [3, 17]
    assert rep["failures"][0]["alt"] == pts.at[3, "alt"]
    assert rep["failures"][0]["residual_norm"] == 1.0
    assert set(model.seen.columns) == {*W_NAMES, *THETA_NAMES}  # no dT_isa passed on


def test_envelope_points_are_reproducible_and_inside_the_envelope():
    a, b = envelope_points(300, seed=1), envelope_points(300, seed=1)
    pd.testing.assert_frame_equal(a, b)
    assert a["alt"].between(0, 42000).all() and a["TRA"].between(20, 100).all()
    assert (a["Mach"] <= 0.85).all() and a["dT_isa"].between(-15, 15).all()
    assert np.all(a[list(THETA_NAMES)].to_numpy() <= 0.0)


def test_engine_model_against_cmapss_has_finite_errors_on_every_channel():
    from engine_model.runtime.shared_model import default_model

    records = compare_reference(default_model(), load_reference(default_reference_path()))
    assert all(r["converged"] for r in records)
    table = error_table(records)
    assert list(table.columns) == list(REFERENCE_CHANNELS)
    assert np.isfinite(table.to_numpy()).all()
    sls = table.loc["0 kft M0 TRA100"]
    design = ["T24", "T30", "T50", "P15", "P30", "Nf", "Nc", "BPR", "W31", "W32", "epr"]
    assert (sls[design].abs() < 1e-4).all(), sls  # the design point, built from these [%]
    assert (table["NRf"].abs() < 0.05).all()  # corrected fan speed held on its schedule
