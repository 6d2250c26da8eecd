"""Requests the CLI must refuse in one line, before anything is written, found by trying to
break it as a user would (2026-11-27): an effect given twice or one that changes nothing, an
empty unit list, a data writer over a feature table, pipeline settings that used to fail
only after the calibration had run, duplicated channels, an empty output name."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from cli.main import app
from engine_model import datasets
from engine_model.physics.effects import parse_effect_spec
from engine_model.validation import InputError
from tests.cli_checks import assert_user_error, cli_runner
from tests.conftest import REPO

TINY = REPO / "data_samples" / "tiny"


@pytest.fixture(scope="module")
def runner():
    return cli_runner()


def run(runner, *args):
    return runner.invoke(app, [str(a) for a in args])


def leftovers(folder):
    return sorted(p.name for p in folder.iterdir())


def test_an_effect_given_twice_is_refused_before_the_fleet_is_written(runner, tmp_path):
    r = run(runner, "simulate", "--preset", "tiny", "--units", "1", "--out", tmp_path / "f",
            "--effect", "customer_bleed:f0=0.02", "--effect", "customer_bleed:f0=0.03")
    assert_user_error(r, "customer_bleed", "more than once")
    assert leftovers(tmp_path) == []


def test_an_effect_sized_at_zero_changes_nothing_whatever_its_shape(runner, tmp_path):
    assert parse_effect_spec("reynolds:n=0,flow_ratio=1").is_neutral()
    assert not parse_effect_spec("reynolds:n=0.05,flow_ratio=0.5").is_neutral()
    r = run(runner, "simulate", "--preset", "tiny", "--units", "1", "--out", tmp_path / "f",
            "--effect", "reynolds:n=0,flow_ratio=1")
    assert_user_error(r, "reynolds", "neutral")
    with pytest.raises(InputError, match="cycle is supplied row by row"):
        parse_effect_spec("sensor_drift:channel=T30,rate=1e-4,cycle=5")
    assert leftovers(tmp_path) == []


@pytest.mark.parametrize("args", [
    ("simulate", "--preset", "tiny", "--units", ""),
    ("calibrate", TINY, "--units", ""),
], ids=["simulate", "calibrate"])
def test_an_empty_unit_list_is_refused_not_read_as_all(runner, tmp_path, args):
    r = run(runner, *args, "--out", tmp_path / "o")
    assert_user_error(r, "--units", "empty list")
    assert leftovers(tmp_path) == []


def test_a_unit_list_takes_ranges():
    from cli.common import parse_units

    assert parse_units("1-3,7") == [1, 2, 3, 7]
    assert parse_units(" 2 - 4 ,10") == [2, 3, 4, 10]
    assert parse_units("1005-1005") == [1005]
    assert parse_units("-3,4") == [-3, 4]  # a negative number, not a range (refused later)
    assert parse_units(None) is None


@pytest.mark.parametrize("args, message", [
    (("simulate", "--preset", "tiny", "--units", "1,,2"), "--units '1,,2': an empty item"),
    (("simulate", "--preset", "tiny", "--units", "1,"), "--units '1,': an empty item"),
    (("discover", TINY, "--candidates", "customer_bleed,customer_bleed"),
     "--candidates customer_bleed,customer_bleed: customer_bleed listed twice"),
    (("calibrate", "compare", TINY, "--methods", "ukf,ukf"), "ukf listed twice"),
    (("simulate", "--preset", "tiny", "--units", "1-3,2"), "--units 1-3,2: unit(s) 2 listed "
     "twice"),
    (("simulate", "--preset", "tiny", "--units", "3-1"), "range 3-1 runs backwards"),
    (("simulate", "--preset", "tiny", "--units", "1-2000000"), "names more than 1,000,000"),
    (("calibrate", TINY, "--units", "1-x"), "expected comma-separated integers or ranges"),
], ids=["two-commas", "trailing-comma", "candidate-twice", "method-twice", "unit-in-a-range",
        "backwards-range", "huge-range", "not-a-range"])
def test_a_list_with_an_empty_item_or_an_item_twice_is_refused(runner, tmp_path, args,
                                                                message):
    out = () if "compare" in args else ("--out", tmp_path / "o")  # compare only prints
    r = run(runner, *args, *out)
    assert_user_error(r, message)
    assert leftovers(tmp_path) == []


def test_a_data_writer_does_not_replace_a_feature_table(runner, tmp_path):
    """simulate and import write data; a feature table (calibrate's output, with its
    calibration record) in their way is refused without --overwrite."""
    df, meta = datasets.read_dataset(TINY, units=[1])
    df = df[df["cycle"] <= 2]
    feats = datasets.write_parquet(df, tmp_path / "feats", {**meta, "calibration": {"x": 1}})
    r = run(runner, "simulate", "--preset", "tiny", "--units", "2", "--out", feats)
    assert_user_error(r, "feats", "--overwrite")
    assert "calibration" in datasets.read_metadata(feats)
    # a feature table written whole replaces a feature table, and data replace data
    datasets.write_parquet(df, feats, {**meta, "calibration": {"x": 2}})
    raw = datasets.write_parquet(df, tmp_path / "raw", meta)
    datasets.write_parquet(df, raw, meta)
    with pytest.raises(InputError, match="--overwrite"):
        datasets.write_parquet(df, raw, {**meta, "calibration": {"x": 3}})


@pytest.mark.parametrize("table, fragment", [
    ('[simulate]\npreset = "tiny"\nseed = -1\n', "[simulate] seed -1"),
    ("[calibrate]\ndrift = 0.0\n", "[calibrate] drift must be > 0"),
    ('[train]\ndevice = "tpu"\n', "[train] device must be auto, cpu or cuda"),
    ("[train]\nval_fraction = 2.0\n", "[train] val_fraction (validation fraction)"),
    ('[discover]\ncandidates = ["nope"]\n', "[discover] candidates: unknown effect 'nope'"),
    ("[train]\nval_units = [99]\n", "[train] val_units: unit(s) 99"),
], ids=["seed", "drift", "device", "val-fraction", "candidates", "val-units"])
def test_pipeline_settings_are_refused_before_any_stage(runner, tmp_path, table, fragment):
    config = tmp_path / "p.toml"
    config.write_text(table)
    r = run(runner, "pipeline", "--config", config, "--out", tmp_path / "run")
    assert_user_error(r, fragment, code=None)
    assert not (tmp_path / "run").exists()


def test_duplicated_channels_and_sensors_are_refused(runner, tmp_path):
    from calibration.adaptation.data import fleet_data

    df, _ = datasets.read_dataset(TINY, units=[1])
    with pytest.raises(InputError, match="T30 listed twice"):
        fleet_data(df.assign(condition=1), ("T30", "T30"))
    r = run(runner, "calibrate", TINY, "--sensors", "T30,T30", "--out", tmp_path / "o")
    assert_user_error(r, "--sensors T30,T30: T30 listed twice")
    r = run(runner, "calibrate", TINY, "--method", "mhe", "--stride", "0", "--out",
            tmp_path / "o")
    assert_user_error(r, "stride 0")
    r = run(runner, "discover", TINY, "--seed", "-1", "--out", tmp_path / "o")
    assert_user_error(r, "seed -1")
    assert leftovers(tmp_path) == []


def test_calibrate_refuses_a_nan_rul_naming_unit_and_row(runner, tmp_path):
    df, meta = datasets.read_dataset(TINY, units=[1, 2])
    df = df[df["cycle"] <= 2].reset_index(drop=True)
    df["RUL"] = df["RUL"].astype(float)
    df.loc[df.index[df["unit"] == 2][3], "RUL"] = np.nan
    data = datasets.write_parquet(df, tmp_path / "d", meta)
    r = run(runner, "calibrate", data, "--out", tmp_path / "f")
    assert_user_error(r, "unit 2, row 4: column RUL = nan")
    assert not (tmp_path / "f").exists()


def test_metadata_unit_lists_and_output_names_are_checked():
    """A metadata ``test_units`` that is not a list (evaluate used to read "12" as units 1
    and 2); an empty --out name for predict."""
    from prognostics.outputs import per_cycle_path
    from prognostics.splits import metadata_units

    with pytest.raises(InputError, match="metadata test_units must be a list"):
        metadata_units({"test_units": "12"}, "test_units")
    assert metadata_units({}, "test_units") is None
    assert metadata_units({"test_units": [11, 14]}, "test_units") == [11, 14]
    with pytest.raises(InputError, match="a file name is needed"):
        per_cycle_path("")


def test_predict_recognises_its_own_table_with_a_health_state_column(tmp_path):
    from prognostics.outputs import PREDICTIONS

    table = tmp_path / "p.csv"
    pd.DataFrame({"unit": [1], "cycle": [1], "t": [0.0], "RUL": [5], "hs": [1],
                  "RUL_pred": [4.0]}).to_csv(table, index=False)
    assert PREDICTIONS.ours(table)


def test_an_empty_scheduler_address_and_a_single_condition_adaptation_are_refused(runner,
                                                                                   tmp_path):
    from calibration.adaptation import adapt

    r = run(runner, "simulate", "--preset", "tiny", "--units", "1", "--scheduler", "",
            "--out", tmp_path / "f")
    assert_user_error(r, "--scheduler: empty address")
    assert leftovers(tmp_path) == []
    df, _ = datasets.read_dataset(TINY, units=[1, 2])
    with pytest.raises(InputError, match="one operating condition"):
        adapt(df.assign(condition=1), ("T30", "T50"))


def test_a_customer_bleed_that_would_add_air_is_refused():
    with pytest.raises(InputError, match=r"bleed fraction .* -0.0175 < 0"):
        parse_effect_spec("customer_bleed:f0=0.005,f_alt=-0.005")
    parse_effect_spec("customer_bleed:f0=0,f_alt=0.0046")  # the FD002 adaptation's: fine


@pytest.mark.parametrize("args", [
    ("model", "envelope", "--n", "2", "--seed", "-1"),
    ("adapt", TINY, "--out", "a.json", "--seed", "-1"),
], ids=["envelope", "adapt"])
def test_a_negative_seed_is_refused_in_one_line(runner, args):
    r = run(runner, *args)
    assert_user_error(r, "--seed", "greater than or equal to 0")


@pytest.mark.parametrize("overwrite", [(), ("--overwrite",)], ids=["plain", "overwrite"])
def test_the_packaged_sample_fleet_is_never_an_output(runner, overwrite):
    """hyprog wrote data_samples/tiny, so by the ownership rule alone a simulate could replace
    it (an audit did, by accident): a package's folder is never an output."""
    before = sorted(p.stat().st_size for p in TINY.rglob("*.parquet"))
    r = run(runner, "simulate", "--preset", "tiny", "--units", "1", "--out", TINY, "--quiet",
            *overwrite)
    assert_user_error(r, "is inside hyprog's package", "not even with --overwrite")
    assert sorted(p.stat().st_size for p in TINY.rglob("*.parquet")) == before


def _path_requests():
    """``(command path, arguments)``: every path parameter of every command given ``""``."""
    import typer.main

    from cli.common import names_a_path

    def walk(cmd, names):
        if hasattr(cmd, "commands"):
            for name, sub in cmd.commands.items():
                yield from walk(sub, (*names, name))
            return
        positional = [p for p in cmd.params if p.param_type_name == "argument"]
        for p in cmd.params:
            if not names_a_path(p.type_descriptor.annotation):
                continue
            if p.param_type_name == "argument":
                before = ["x"] * positional.index(p)
                yield names, (*before, ""), p.name.upper()
            else:
                yield names, (p.opts[0], ""), p.opts[0]

    return list(walk(typer.main.get_command(app), ()))


PATH_REQUESTS = _path_requests()


def test_every_command_has_path_parameters_to_check():
    """A list written by hand, so that ``names_a_path`` missing a kind of path annotation
    (and the test above then skipping its parameters) shows here."""
    found = {(names, culprit) for names, _, culprit in PATH_REQUESTS}
    assert {(("train",), "FEATURES"), (("train",), "--out"), (("predict",), "MODEL_DIR"),
            (("predict",), "--out"), (("calibrate", "run"), "DATA"),
            (("calibrate", "run"), "--out"), (("calibrate", "run"), "--model-effects"),
            (("adapt",), "--out"), (("pipeline",), "--config"), (("pipeline",), "--out"),
            (("simulate",), "--out")} <= found


@pytest.mark.parametrize("names,args,culprit", PATH_REQUESTS,
                         ids=[" ".join((*n, c)) for n, _, c in PATH_REQUESTS])
def test_an_empty_path_is_refused_not_read_as_the_current_folder(runner, tmp_path, monkeypatch,
                                                                  names, args, culprit):
    monkeypatch.chdir(tmp_path)
    r = run(runner, *names, *args)
    assert_user_error(r, culprit, "empty path")
    assert leftovers(tmp_path) == []


def test_a_bad_estimator_option_is_refused_before_the_model_is_built(runner, tmp_path,
                                                                       monkeypatch):
    """The estimator's options are checked before the data are checked against the engine
    model (whose first build compiles it: half a minute spent before a refusal)."""
    import calibration.calibrate_fleet as cf
    from calibration import CalibrationSetup

    def no_model(*args, **kwargs):
        raise AssertionError("the engine model was built before the options were checked")

    monkeypatch.setattr(cf, "worker_model", no_model)
    r = run(runner, "calibrate", TINY, "--method", "mhe", "--stride", "0", "--out",
            tmp_path / "o")
    assert_user_error(r, "stride 0")
    with pytest.raises(InputError, match="'ukf': no option stride"):
        cf.calibrate_fleet(TINY, "ukf", CalibrationSetup(), options={"stride": 3})
    # the measured noise's consistent estimate runs a UKF calibration, the drift's MLE builds
    # the model, compare calibrates with each method in turn: the options come before all
    import calibration.compare as cc
    import calibration.consistency as cons
    import calibration.discrepancy.drift_mle as dm

    monkeypatch.setattr(cons, "with_measured_noise", no_model)
    monkeypatch.setattr(dm, "setup_with_drift_mle", no_model)
    monkeypatch.setattr(cc, "calibrate_fleet", no_model)
    r = run(runner, "calibrate", TINY, "--method", "mhe", "--stride", "0", "--drift", "mle",
            "--model-error", "consistent", "--out", tmp_path / "o")
    assert_user_error(r, "stride 0")
    assert_user_error(run(runner, "calibrate", "compare", TINY, "--methods", "ukf,mhe",
                          "--stride", "0", "--drift", "mle"), "stride 0")
    # an option no listed method takes would do nothing: refused, not ignored
    assert_user_error(run(runner, "calibrate", "compare", TINY, "--methods", "ukf,ekf",
                          "--window", "30"), "--window", "mhe")
    assert leftovers(tmp_path) == []


def test_an_estimator_taking_any_keyword_refuses_no_option_name():
    """``**kwargs`` in an estimator's ``__init__`` is not an option called "kwargs". (Only
    the class methods are called: the estimators are never built, so they need no
    ``estimate``.)"""
    from calibration.base import Estimator

    class Open(Estimator):
        name = "open"

        def __init__(self, model=None, *args, gain=1.0, **kwargs):
            super().__init__(model)

    assert Open.option_names() == {"gain"}
    Open.check_options({"gain": 2.0, "anything": 1})

    class Closed(Open):
        def __init__(self, model=None, gain=1.0):
            super().__init__(model)

    assert Closed.option_names() == {"gain"}
    with pytest.raises(InputError, match="'open': no option kwargs"):
        Closed.check_options({"kwargs": {}})
