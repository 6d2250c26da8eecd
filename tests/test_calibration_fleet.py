"""Fleet calibration: task planning, effects held in the model, resumable feature tables,
the comparison against truth and the CRB, and the CLI. That worker processes and a Dask cluster
give the serial run's files byte for byte is tested through the pipeline
(tests/test_pipeline_parallel.py)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from calibration import CalibrationSetup, UnobservableWarning, get_estimator
from calibration.calibrate_fleet import (
    calibrate_fleet,
    features_of,
    plan_tasks,
    read_groups,
    unit_rows,
)
from calibration.compare import compare, format_report
from calibration.crb import posterior_crb, unit_posterior_crb, unit_sensitivities, windowed_crb
from calibration.result import HAT_NAMES
from calibration.series import prepare_unit
from cli.main import app
from engine_model import datasets
from engine_model.channels import PAPER_THETA
from engine_model.validation import InputError
from tests.conftest import REPO

TINY = REPO / "data_samples" / "tiny"
SETUP = CalibrationSetup(drift=0.01)  # tiny: 10-cycle lives, fast wear


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """Units 1-3 of the committed tiny fleet, first three flights each, as a dataset."""
    df, meta = datasets.read_dataset(TINY, units=[1, 2, 3])
    df = df[df["cycle"] <= 3].reset_index(drop=True)
    path = tmp_path_factory.mktemp("small") / "fleet"
    datasets.write_parquet(df, path, meta)
    return path, df


@pytest.fixture(scope="module")
def serial(small):
    path, _ = small
    return calibrate_fleet(path, "ukf", SETUP)


def test_plan_balances_lockstep_groups_and_splits_windowed_methods():
    lengths = {1: 100, 2: 90, 3: 60, 4: 50, 5: 40}
    groups = plan_tasks(lengths, "ukf", 2)
    loads = sorted(sum(lengths[u] for u in g) for g in groups)
    # longest-processing-time first: 100+50+40 / 90+60
    assert loads == [150, 190] and sorted(u for g in groups for u in g) == [1, 2, 3, 4, 5]
    assert plan_tasks(lengths, "mhe", 2) == [[1], [2], [3], [4], [5]]
    # a lockstep group is cut so that no task holds more than max_rows samples (one unit
    # at least): memory bounded whatever the fleet
    assert plan_tasks(lengths, "ukf", 1, max_rows=150) == [[1], [2, 3], [4, 5]]
    assert plan_tasks({1: 500, 2: 10}, "ekf", 1, max_rows=100) == [[1], [2]]


def test_units_are_listed_without_reading_the_fleet(small):
    from calibration.calibrate_fleet import dataset_units
    from engine_model import InputError

    path, _ = small
    assert dataset_units(path) == [1, 2, 3] and dataset_units(path, [3, 1]) == [1, 3]
    with pytest.raises(InputError, match="9"):
        dataset_units(path, [1, 9])


def test_effects_are_held_in_the_model_and_in_the_resume_settings(small, tmp_path, serial):
    """``effects=``: the model with a customer bleed held at f0 = 0.02 explains the data
    otherwise than the base model (other theta_hat); a spec string and an Effect give the
    same canonical entry in the metadata; resuming with other effects, or none, is refused
    naming them; a bad specification fails before anything is written."""
    from engine_model import InputError
    from engine_model.physics.effects import parse_effect_spec

    path, _ = small
    out = tmp_path / "features"
    bleed = "customer_bleed:f0=0.02"
    run = calibrate_fleet(path, "ukf", SETUP, units=[1], out=out, effects=[bleed])
    spec = parse_effect_spec(bleed).spec()
    assert run.effects == [spec]
    assert datasets.read_metadata(out)["calibration"]["effects"] == [spec]
    with_bleed = run.results[1].theta_hat.to_numpy()
    base = serial.results[1].theta_hat.to_numpy()
    assert np.abs(with_bleed - base).max() > 1e-4  # the bleed is in the model
    again = calibrate_fleet(path, "ukf", SETUP, units=[1], out=out,
                            effects=[parse_effect_spec(bleed)])
    assert again.skipped == [1] and not again.units
    with pytest.raises(InputError, match="unit 1 was calibrated with other settings.*effects"):
        calibrate_fleet(path, "ukf", SETUP, units=[2], out=out)
    with pytest.raises(InputError, match="effects"):
        calibrate_fleet(path, "ukf", SETUP, units=[2], out=out,
                        effects=["customer_bleed:f0=0.01"])
    with pytest.raises(InputError, match="no_such_effect"):
        calibrate_fleet(path, "ukf", SETUP, units=[2], out=tmp_path / "other",
                        effects=["no_such_effect"])
    assert datasets.written_units(out) == [1] and not (tmp_path / "other").exists()


def test_serial_run_equals_the_estimator_on_each_unit(serial, small):
    _, df = small
    est = get_estimator("ukf")
    for u in (1, 3):
        one = df[df["unit"] == u].reset_index(drop=True)
        alone = est.estimate(one, SETUP)
        np.testing.assert_allclose(serial.results[u].theta_hat.to_numpy(),
                                   alone.theta_hat.to_numpy(), rtol=1e-9, atol=1e-12)
    feats = features_of(serial)
    assert len(feats) == len(df)
    for c in (*HAT_NAMES, *(q + "_hat" for q in PAPER_THETA),
              *(q + "_hat_std" for q in PAPER_THETA), *df.columns):
        assert c in feats.columns
    assert serial.samples == len(df) and serial.samples_per_second > 0


def test_unreachable_scheduler_is_a_clear_error(small):
    from engine_model import InputError

    path, _ = small
    with pytest.raises(InputError, match="tcp://127.0.0.1:9: cannot connect"):
        calibrate_fleet(path, "ukf", SETUP, scheduler="tcp://127.0.0.1:9")


def test_features_are_resumable_and_never_half_written(small, tmp_path, serial):
    path, _ = small
    out = tmp_path / "features"
    first = calibrate_fleet(path, "ukf", SETUP, units=[2], out=out)
    assert datasets.written_units(out) == [2] and not first.skipped
    part = out / "unit=2" / "part-0.parquet"
    stamp = part.stat().st_mtime_ns

    class Stop(Exception):
        pass

    def stop_after_first(done, total):
        if done == 1:
            raise Stop

    # one unit per task (map_cycle would; here: ukf with 2 groups run serially) ...
    with pytest.raises(Stop):
        calibrate_fleet(path, "ukf", SETUP, out=out, progress=stop_after_first,
                        jobs=1, units=[1, 3])
    written = datasets.written_units(out)
    assert 2 in written and len(written) == 2  # unit 2 plus the one finished before the stop
    assert not list(out.rglob(".*tmp*"))
    final = calibrate_fleet(path, "ukf", SETUP, out=out)
    assert sorted(final.skipped) == written and part.stat().st_mtime_ns == stamp
    feats, meta = datasets.read_dataset(out)
    assert sorted(feats["unit"].unique()) == [1, 2, 3]
    assert meta["calibration"]["method"] == "ukf" and meta["preset"] == "tiny"
    ref = features_of(serial)
    np.testing.assert_allclose(feats["HPT_eff_mod_hat"], ref["HPT_eff_mod_hat"], rtol=1e-9,
                               atol=1e-12)
    from engine_model import InputError

    with pytest.raises(InputError, match="other settings"):
        calibrate_fleet(path, "ekf", SETUP, out=out)


def test_compare_reports_errors_and_bounds(small):
    path, df = small
    rep = compare(path, ("ukf", "map_cycle"), SETUP, units=[1])
    one = df[df["unit"] == 1].reset_index(drop=True)
    res = get_estimator("ukf").estimate(one, SETUP)
    err = res.theta_hat.to_numpy() - one[list(PAPER_THETA)].to_numpy()
    from calibration.base import default_model

    series = prepare_unit(one, SETUP)
    truth = one[list(PAPER_THETA)].to_numpy()
    crb = unit_posterior_crb(default_model(), series, SETUP, truth)
    S = unit_sensitivities(default_model(), series, SETUP, truth)
    per_cycle = windowed_crb(S, one["cycle"].to_numpy(), np.diag(SETUP.prior_std_vec() ** 2),
                             arrival=False)
    for j, q in enumerate(PAPER_THETA):
        p = rep["methods"]["ukf"]["params"][q]
        assert p["rmse"] == pytest.approx(np.sqrt(np.mean(err[:, j] ** 2)), rel=1e-9)
        assert p["bias"] == pytest.approx(np.mean(err[:, j]), rel=1e-9, abs=1e-15)
        assert p["crb"] == pytest.approx(np.sqrt(np.mean(crb[:, j, j])), rel=1e-9)
        std = res.theta_std[q + "_hat_std"].to_numpy()
        assert p["consistency"] == np.mean(np.abs(err[:, j]) <= 1.96 * std)
        assert p["std"] == pytest.approx(np.mean(std), rel=1e-9)
        c = rep["methods"]["map_cycle"]["params"][q]
        assert c["crb"] == pytest.approx(np.sqrt(np.mean(per_cycle[:, j, j])), rel=1e-9)
    r = rep["methods"]["ukf"]["residual_variance"]
    assert r == pytest.approx(np.nanmean(res.residuals.to_numpy() ** 2), rel=1e-9)
    text = format_report(rep)
    assert "### ukf" in text and "RMSE / CRB" in text
    json.dumps(rep, allow_nan=True)


def test_the_random_walk_mhe_is_bounded_under_its_own_walk(small):
    """The random-walk MHE walks in operating time whatever ``drift_per`` (calibration.mhe):
    compare's bound for it is the posterior CRB with steps ``q^2 dt``, not the filters' drift
    per cycle (which differs on data with cycles)."""
    from calibration.base import default_model
    from calibration.compare import _bound_kind, unit_bound

    _, df = small
    one = df[df["unit"] == 1].reset_index(drop=True)
    assert _bound_kind("mhe", {"mode": "random_walk"}) == "posterior_time"
    assert _bound_kind("ukf", {}) == "posterior"
    series = prepare_unit(one, SETUP)
    assert not np.allclose(series.dtau_h, series.dt_h)  # per cycle here
    S = unit_sensitivities(default_model(), series, SETUP, one[list(PAPER_THETA)].to_numpy())
    var, _ = unit_bound(default_model(), one, SETUP, "posterior_time", {}, S)
    ref = posterior_crb(S, SETUP.drift ** 2 * series.dt_h, np.diag(SETUP.prior_std_vec() ** 2))
    np.testing.assert_allclose(var, np.diagonal(ref, axis1=1, axis2=2), rtol=1e-12)
    per_cycle, _ = unit_bound(default_model(), one, SETUP, "posterior", {}, S)
    assert not np.allclose(var, per_cycle)


def test_compare_needs_the_truth(small):
    from engine_model import InputError

    _, df = small
    with pytest.raises(InputError, match="compare needs the true values of HPT_eff_mod"):
        compare(df.drop(columns=["HPT_eff_mod"]), ("ukf",), SETUP)


# ----------------------------------------------------------------------------- CLI
runner = CliRunner()


def test_cli_calibrate_writes_features_and_resumes(small, tmp_path):
    path, df = small
    out = tmp_path / "feat"
    args = ["calibrate", str(path), "--method", "ukf", "--out", str(out), "--drift", "0.01",
            "--units", "1,2"]
    r = runner.invoke(app, [*args, "--json"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.output)
    assert rep["samples"] == int(df["unit"].isin([1, 2]).sum()) and rep["skipped"] == []
    r = runner.invoke(app, [*args, "--json"])
    assert json.loads(r.output)["skipped"] == [1, 2]
    feats, _ = datasets.read_dataset(out)
    assert {"T48_hat", "W50_hat", "HPT_eff_mod_hat", "LPT_flow_mod_hat_std"} <= set(feats)
    r = runner.invoke(app, ["calibrate", str(path), "--method", "ukf", "--out",
                            str(tmp_path / "f2"), "--units", "1"])
    assert r.exit_code == 0 and "wrote" in r.output


def test_cli_calibrate_sensor_subset_reports_unobservable(small, tmp_path, capfd):
    path, _ = small
    r = runner.invoke(app, ["calibrate", str(path), "--method", "ekf", "--units", "1",
                            "--sensors", "P2,P15", "--out", str(tmp_path / "f"), "--json"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.output)
    # the inlet and the bypass duct do not separate one of the three turbine parameters from
    # the others (which one depends on the operating points' sensitivities: LPT efficiency
    # before the bleed-valve schedule of issue 12, HPT efficiency since)
    weak = rep["units"]["1"]["unobservable"]
    assert len(weak) == 1 and weak[0] in PAPER_THETA, weak
    assert [w for w in rep["warnings"] if "cannot be observed" in w] == [
        f"health parameter(s) {weak[0]} cannot be observed with sensors P2, P15 in 1 of 1 "
        "units (unit 1: the Fisher information is rank-deficient, or the data pin them down "
        "less than the prior std 0.02 does); held at the prior mean, reported as NaN"]
    # worker processes: the same report, and no warning of theirs on stderr as Python
    # prints it (file and line of the source)
    r2 = runner.invoke(app, ["calibrate", str(path), "--method", "ekf", "--units", "1,2",
                             "--jobs", "2", "--sensors", "P2,P15", "--out",
                             str(tmp_path / "f2"), "--json"])
    assert r2.exit_code == 0, r2.output
    rep2 = json.loads(r2.stdout)
    # the workers write to the process's file descriptor 2, which only capfd sees
    assert "UnobservableWarning" not in capfd.readouterr().err
    assert [w for w in rep2["warnings"] if "cannot be observed" in w] == [
        w.replace("1 of 1 units (unit 1:", "2 of 2 units (units 1, 2:")
        for w in rep["warnings"] if "cannot be observed" in w]
    feats, _ = datasets.read_dataset(tmp_path / "f")
    for q in PAPER_THETA:
        assert (feats[q + "_hat"].isna().all() if q == weak[0]
                else feats[q + "_hat"].notna().all()), q
    # nothing observable: a one-line error, nothing written
    r = runner.invoke(app, ["calibrate", str(path), "--method", "ekf", "--units", "1",
                            "--sensors", "P2", "--out", str(tmp_path / "g")])
    assert r.exit_code == 2 and "cannot be observed" in r.output
    assert not (tmp_path / "g").exists()


def test_cli_compare_json(small):
    path, _ = small
    r = runner.invoke(app, ["calibrate", "compare", str(path), "--methods", "ekf",
                            "--units", "3", "--drift", "0.01", "--json"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.output)
    assert set(rep["methods"]) == {"ekf"} and rep["methods"]["ekf"]["bound"] == "posterior"


@pytest.mark.parametrize("args, fragment", [
    (["--method", "pf"], "'pf' is not one of 'ukf', 'ekf', 'mhe', 'map_cycle'"),
    (["--params", "HPT_eff"], "unknown health parameter(s) HPT_eff"),
    (["--sensors", "T99"], "unknown sensor(s) T99"),
    (["--window", "30"], "--window: options of the mhe method, not ukf"),
    (["--units", "1,x"], "expected comma-separated integers"),
    (["--units", "42"], "42"),
])
def test_cli_bad_input_is_one_line(small, tmp_path, args, fragment):
    path, _ = small
    out = tmp_path / "f"
    r = runner.invoke(app, ["calibrate", str(path), "--out", str(out), *args])
    assert r.exit_code == 2
    assert r.output.startswith("error:") and fragment in r.output
    assert "Traceback" not in r.output and len(r.output.strip().splitlines()) == 1
    assert not out.exists()


def test_cli_missing_data_file(tmp_path):
    r = runner.invoke(app, ["calibrate", str(tmp_path / "nope"), "--out", str(tmp_path / "f")])
    assert r.exit_code == 2 and "no such file" in r.output


def test_the_client_reads_short_units_in_groups_bounded_by_rows(tmp_path):
    """The checks before the work read many short units at once (C-MAPSS: one read for a
    fleet), in unit order, never more than the row budget a group unless one unit is larger;
    row counts come from the part files' footers."""
    rows = {1: 150, 2: 200, 3: 700, 4: 90, 5: 40}
    assert read_groups([1, 2, 3, 4, 5], rows, max_rows=400) == [[1, 2], [3], [4, 5]]
    assert read_groups([1, 2, 3, 4, 5], rows, max_rows=10_000) == [[1, 2, 3, 4, 5]]
    assert read_groups([1, 2], None) == [[1], [2]]  # unknown sizes: one unit a read
    df = pd.DataFrame({"unit": np.repeat([1, 2], [3, 5]), "cycle": np.r_[1:4, 1:6],
                       "alt": 0.0, "Mach": 0.0, "TRA": 100.0, "T2": 518.67})
    path = datasets.write_parquet(df, tmp_path / "fleet", {})
    assert unit_rows(path, [1, 2]) == {1: 3, 2: 5}
    assert unit_rows(tmp_path / "fleet.h5", [1]) is None


def test_bound_warnings_are_summarised_per_parameter_over_the_fleet():
    """A 100-unit C-MAPSS fleet printed a line per unit and parameter at a bound (hundreds of
    lines); the command now prints one per parameter and bound, the JSON keeps every unit's.
    A bound hit by most of the fleet points to adapting the model (a shared mismatch)."""
    from calibration.unit_check import AT_BOUND, FLEET_AT_BOUND, summarise_bound_hits

    units = {u: {"samples": 200, "at_bound": [
        {"param": "LPT_flow_mod_hat", "bound": 0.05, "samples": 10 * u, "of": 200}]}
        for u in range(1, 8)}
    units[8] = {"samples": 150, "at_bound": [
        {"param": "HPT_eff_mod_hat", "bound": -0.15, "samples": 1, "of": 150}]}
    units[9] = {"samples": 90, "at_bound": []}
    lines = summarise_bound_hits(units)
    assert lines == [
        "LPT_flow_mod_hat is at its bound 0.05 in 7 of 9 units (units 1, 2, 3, 4, 5, ...; "
        f"280 of their 1,400 samples): {AT_BOUND}; {FLEET_AT_BOUND}",
        f"HPT_eff_mod_hat is at its bound -0.15 in 1 of 9 units (unit 8; 1 of their 150 "
        f"samples): {AT_BOUND}"]
    assert summarise_bound_hits({1: {"samples": 5, "at_bound": []}}) == []
    # what calibrate prints and the pipeline reports: other warnings kept, a unit's own bound
    # lines replaced by the fleet's
    from calibration.unit_check import fleet_warnings

    units[1]["warnings"] = [f"unit 1: LPT_flow_mod_hat is at its bound 0.05 ...: {AT_BOUND}"]
    said = ["health parameter(s) LPT_flow_mod cannot be observed", *units[1]["warnings"]]
    assert fleet_warnings(said, units) == [said[0], *lines]


def test_a_library_caller_is_warned_once_for_the_fleet(small):
    """calibrate_fleet: one UnobservableWarning for the units that share the unobservable
    parameters, attributed to the caller's line, and the same line in the run's warnings."""
    import warnings

    path, _ = small
    setup = CalibrationSetup(sensors=("P2", "P15"), drift=0.01)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        run = calibrate_fleet(path, "ekf", setup, units=[1, 2])
    said = [w for w in caught if issubclass(w.category, UnobservableWarning)]
    assert len(said) == 1 and "in 2 of 2 units (units 1, 2:" in str(said[0].message)
    assert said[0].filename == __file__
    assert [w for w in run.warnings if "cannot be observed" in w] == [str(said[0].message)]


def test_unobservable_parameters_are_summarised_over_the_fleet():
    """FD003 with every parameter printed the same unobservability warning for each of its
    66 units; one line per set of parameters and sensors now, the units counted."""
    from calibration.unit_check import summarise_unobservable

    both = {"unobservable": ["fan_eff_mod", "LPT_flow_mod"], "sensors": ["T24", "T30"]}
    units = {u: both for u in range(1, 8)}
    units[8] = {"unobservable": ["fan_eff_mod"], "sensors": ["T24"]}
    units[9] = {"unobservable": [], "sensors": ["T24", "T30"]}
    lines = summarise_unobservable(units, 0.02)
    assert len(lines) == 2
    assert lines[0].startswith("health parameter(s) fan_eff_mod, LPT_flow_mod cannot be "
                               "observed with sensors T24, T30 in 7 of 9 units (units 1, 2, "
                               "3, 4, 5, ...: ")
    assert "prior std 0.02" in lines[0] and lines[0].endswith("reported as NaN")
    assert "with sensors T24 in 1 of 9 units (unit 8: " in lines[1]
    assert summarise_unobservable({1: units[9]}, 0.02) == []


def test_the_consistent_model_error_brings_the_mean_nis_per_channel_to_one(tmp_path):
    """On simulated data the filter is consistent as it is (model error 0); with T30 1 % off
    the model, the model error found makes the fleet's mean NIS per channel 1 (within the
    search's tolerance: consistent there, not at the next smaller value)."""
    from calibration.consistency import RTOL, consistent_model_error, fleet_nis

    df, _ = datasets.read_dataset(REPO / "data_samples" / "tiny", units=[1, 2])
    df = df.groupby("unit").head(400).reset_index(drop=True)
    e, nis = consistent_model_error(df, CalibrationSetup())
    assert e == 0.0 and 0.5 < nis <= 1.0
    biased = df.assign(T30=df["T30"] * 1.01)
    assert fleet_nis(biased, CalibrationSetup()) > 2.0
    e, nis = consistent_model_error(biased, CalibrationSetup())
    assert 1e-3 < e < 1e-2 and 0.9 < nis <= 1.0
    assert fleet_nis(biased, CalibrationSetup(model_error=e / (1 + 2 * RTOL))) > 1.0
    from tests.cli_checks import assert_user_error, cli_runner

    r = cli_runner().invoke(app, ["calibrate", str(REPO / "data_samples" / "tiny"), "--out",
                                  str(tmp_path / "f"), "--model-error", "often"])
    assert_user_error(r, "--model-error often", code=None)
    assert not (tmp_path / "f").exists()


def test_a_dataframe_is_checked_and_sorted_as_a_file_is(serial, small):
    """The rows of a DataFrame in another order give the same estimates as the file (the
    filter runs along each unit's rows, so they are sorted first); bad keys are one line."""
    path, df = small
    shuffled = df.sample(frac=1.0, random_state=0)
    run = calibrate_fleet(shuffled, "ukf", SETUP, units=[2])
    np.testing.assert_allclose(run.results[2].theta_hat.to_numpy(),
                               serial.results[2].theta_hat.to_numpy(), rtol=1e-9, atol=1e-12)
    for bad, fragment in ((df.assign(unit=df["unit"].astype(str) + "x"), "unit"),
                          (df.assign(cycle=df["cycle"] + 0.5), "cycle"),
                          (df.drop(columns="unit"), "'unit' column")):
        with pytest.raises(InputError, match=fragment):
            calibrate_fleet(bad, "ukf", SETUP)


def test_the_datas_noise_needs_integer_condition_labels(small):
    _, df = small
    table = df.assign(condition=1)
    table.loc[5, "condition"] = np.nan
    with pytest.raises(InputError, match=r"row 6, column condition = nan"):
        calibrate_fleet(table, "ukf", CalibrationSetup(drift=0.01, noise="data"))
