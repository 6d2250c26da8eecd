"""The ``hyprog`` command line: numbers through the CLI, and errors a user can act on.

The engine model is built once for the module (the process-wide one of
:func:`cli.common.get_model`).
"""

import json
import subprocess
import sys

import pytest

from cli.common import get_model
from cli.main import app
from engine_model.analysis.reference import default_reference_path
from engine_model.analysis.sampling import envelope_points
from engine_model.units import T_STD_K, T_STD_R, k_to_r
from tests.cli_checks import assert_user_error, cli_runner

SLS_T30_R = 1586.4  # C-MAPSS FD002, SLS ISA TRA 100 (the design point)
SLS_CHANNELS = ("T24", "T30", "T50", "P15", "P30", "Nf", "Nc", "BPR", "W31", "W32", "epr")


@pytest.fixture(scope="module")
def runner():
    get_model()  # build (compile or load) the engine model once for the module
    return cli_runner()


def run(runner, *args):
    return runner.invoke(app, list(args))


def test_help_does_not_import_the_engine_model():
    code = ("import sys; from typer.testing import CliRunner; from cli.main import app;"
            " r = CliRunner().invoke(app, ['--help']); assert r.exit_code == 0, r.output;"
            " print('casadi' in sys.modules, 'engine_model' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True)
    assert out.stdout.split() == ["False", "False"]


def test_point_json_at_sls_matches_the_design_point(runner):
    r = run(runner, "model", "point", "--alt", "0", "--mach", "0", "--tra", "100", "--json")
    assert r.exit_code == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["converged"] is True
    assert d["residual_norm"] < 1e-8
    assert d["T30"] == pytest.approx(SLS_T30_R, rel=1e-3)
    assert d["T2"] == pytest.approx(T_STD_R, abs=0.01)  # ISA sea level, static
    # every output channel is there, numeric
    from engine_model import OUTPUT_NAMES

    assert all(isinstance(d[k], float) for k in OUTPUT_NAMES)


def test_point_hot_day_raises_t2_by_dt_isa(runner):
    r = run(runner, "model", "point", "--alt", "0", "--mach", "0", "--tra", "100",
            "--dt-isa", "10", "--json")
    assert r.exit_code == 0, r.stderr
    assert json.loads(r.stdout)["T2"] == pytest.approx(k_to_r(T_STD_K + 10.0), abs=0.01)


def test_point_hpt_efficiency_loss_raises_t48(runner):
    base = ["model", "point", "--alt", "0", "--mach", "0", "--tra", "100", "--json"]
    nominal = json.loads(run(runner, *base).stdout)
    r = run(runner, *base, "--theta", "HPT_eff_mod=-0.02")
    assert r.exit_code == 0, r.stderr
    worn = json.loads(r.stdout)
    assert worn["converged"] is True
    assert worn["HPT_eff_mod"] == -0.02
    # a less efficient HPT extracts less work per degree: more fuel, hotter LPT inlet
    assert worn["T48"] > nominal["T48"] + 1.0
    assert worn["Wf"] > nominal["Wf"]


def test_point_prints_a_table_with_units(runner):
    r = run(runner, "model", "point", "--alt", "35000", "--mach", "0.8", "--tra", "90")
    assert r.exit_code == 0, r.stderr
    for word in ("x_s", "x_v", "extra", "T48", "SmHPC", "degR", "psia", "converged: True"):
        assert word in r.stdout


@pytest.mark.parametrize("bad, fragment", [
    ("FOO=1", "FOO"),
    ("HPT_eff_mod=abc", "abc"),
    ("HPT_eff_mod", "NAME=VALUE"),
    ("HPT_eff_mod=-0.5", "-0.5"),
])
def test_point_bad_theta_is_a_one_line_error(runner, bad, fragment):
    r = run(runner, "model", "point", "--alt", "0", "--mach", "0", "--tra", "100",
            "--theta", bad)
    assert_user_error(r, "--theta", fragment)


def test_point_outside_envelope_names_the_option(runner):
    r = run(runner, "model", "point", "--alt", "60000", "--mach", "0", "--tra", "100")
    assert_user_error(r, "--alt", "60000")
    r = run(runner, "model", "point", "--alt", "0", "--mach", "0", "--tra", "100",
            "--t2", "520", "--dt-isa", "5")
    assert_user_error(r, "--t2", "--dt-isa")


def test_reference_json_sls_row_matches_cmapss(runner):
    r = run(runner, "model", "reference", "--json")
    assert r.exit_code == 0, r.stderr
    rows = json.loads(r.stdout)
    assert len(rows) == 6
    assert all(row["converged"] for row in rows)
    sls = next(row for row in rows if row["alt_kft"] == 0 and row["Mach"] == 0)
    for c in SLS_CHANNELS:
        assert abs(sls[f"{c}_err_pct"]) < 1e-4, (c, sls[f"{c}_err_pct"])  # the design point
        assert sls[f"{c}_err_pct"] == pytest.approx(
            100 * (sls[f"{c}_model"] - sls[f"{c}_ref"]) / sls[f"{c}_ref"])
    # the controller holds corrected fan speed on its TRA schedule at every row
    for row in rows:
        assert abs(row["NRf_err_pct"]) < 0.05
    assert "Ps30_ref" not in sls and "phi_ref" not in sls


def test_reference_missing_csv_names_the_path(runner, tmp_path):
    missing = tmp_path / "no-such-table.csv"
    r = run(runner, "model", "reference", str(missing))
    assert_user_error(r, str(missing))


def test_reference_bad_csv_names_row_and_column(runner, tmp_path):
    good = default_reference_path().read_text().splitlines()
    header, first = good[0], good[1]
    no_mach = tmp_path / "no-mach.csv"
    no_mach.write_text(header.replace("Mach,", "Speed,") + "\n" + first + "\n")
    assert_user_error(run(runner, "model", "reference", str(no_mach)), "Mach")

    cells = first.split(",")
    cells[header.split(",").index("T30")] = "hot"
    not_a_number = tmp_path / "text.csv"
    not_a_number.write_text(header + "\n" + ",".join(cells) + "\n")
    assert_user_error(run(runner, "model", "reference", str(not_a_number)),
                      "row 1", "T30", "hot")

    cells = first.split(",")
    cells[header.split(",").index("Mach")] = "1.5"
    too_fast = tmp_path / "fast.csv"
    too_fast.write_text(header + "\n" + ",".join(cells) + "\n")
    assert_user_error(run(runner, "model", "reference", str(too_fast)), "Mach", "1.5")

    empty = tmp_path / "empty.csv"
    empty.write_text("")
    assert_user_error(run(runner, "model", "reference", str(empty)), str(empty))

    twice = tmp_path / "twice.csv"
    twice.write_text(header + ",T30\n" + first + ",1\n")
    assert_user_error(run(runner, "model", "reference", str(twice)), str(twice), "T30",
                      "more than once")

    names = header.split(",")
    cells = [c if n in ("alt_kft", "Mach", "TRA", "T2") else ("0" if i % 2 else "")
             for i, (n, c) in enumerate(zip(names, first.split(","), strict=True))]
    nothing = tmp_path / "nothing.csv"
    nothing.write_text(header + "\n" + ",".join(cells) + "\n")
    assert_user_error(run(runner, "model", "reference", str(nothing)), str(nothing),
                      "nothing to compare")


def test_envelope_json_all_points_converge(runner):
    r = run(runner, "model", "envelope", "--n", "50", "--json")
    assert r.exit_code == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["n_points"] == 50
    assert d["convergence_rate"] == 1.0
    assert d["n_failed"] == 0 and d["failures"] == []


def test_envelope_points_stay_inside_the_civil_envelope():
    pts = envelope_points(500, seed=3)
    assert pts["alt"].between(0, 42000).all()
    assert (pts["Mach"] <= 0.85).all() and (pts["Mach"] >= 0).all()
    assert pts["TRA"].between(20, 100).all()
    assert pts["dT_isa"].between(-15, 15).all()
    from engine_model import THETA_NAMES

    assert pts[list(THETA_NAMES)].stack().between(-0.05, 0).all()
