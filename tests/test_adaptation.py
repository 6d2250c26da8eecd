"""Adapting the engine model to a fleet (calibration.adaptation): noise from the data, the
joint fit of shared effects and each engine's health, selection by leaving a condition out,
the artefact and ``calibrate --model-effects``.

The fleets are simulated at C-MAPSS's six FD002 operating points (data_samples), engines new
with a manufacturing scatter of their health, C-MAPSS-like noise."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from calibration.adaptation import adapt, assess, load_adapted, write_adapted
from calibration.adaptation.adapt import prebuilt_groups, record_groups
from calibration.adaptation.data import MODEL_ERROR, fleet_data
from calibration.adaptation.fleet_fit import MAX_ITER, Shared, evaluate, fit_fleet
from calibration.adaptation.groups import build_groups
from calibration.adaptation.selection import (
    MIN_GAIN,
    TOP,
    OutOfSample,
    enters,
    select,
    shared_of,
)
from calibration.discrepancy.candidates import CandidateModel
from calibration.measurement_noise import noise_from_data
from engine_model import OUTPUT_NAMES, THETA_NAMES, EngineModel
from engine_model.analysis.reference import default_reference_path, load_reference, reference_w
from engine_model.physics.effects import parse_effect_spec
from engine_model.validation import InputError

TINY = Path(__file__).resolve().parents[1] / "data_samples" / "tiny"
CHANNELS = ("T24", "T30", "T50", "P15", "P30", "Nf", "Nc")
#: noise std per channel (about C-MAPSS FD002's within-engine early-life levels, P15 coarser)
NOISE = {"T24": 0.3, "T30": 4.0, "T50": 4.0, "P15": 0.02, "P30": 0.4, "Nf": 0.03, "Nc": 4.0}
CANDIDATES = ("design_scaling", "map_scaling", "nozzle_area")
#: HPC efficiency 2 % lower at the part-power condition (corrected speed about 3.4 % below
#: design): map_scaling eff_1 = 0.6 per unit of (n_corr - 1)
SHAPE = "map_scaling:component=HPC,eff_1=0.6"


def simulated_fleet(truth_effects=(), units=12, cycles=18, seed=0) -> pd.DataFrame:
    """Engines flying one of the six FD002 conditions per cycle (seeded), health drawn per
    engine (std 0.4 %), readings of ``CHANNELS`` with Gaussian noise ``NOISE``."""
    rng = np.random.default_rng(seed)
    w6 = reference_w(load_reference(default_reference_path())).to_numpy(float)
    truth = EngineModel(effects=[parse_effect_spec(s) for s in truth_effects], compiled=False)
    rows = []
    for u in range(1, units + 1):
        theta = rng.normal(0.0, 0.004, len(THETA_NAMES))
        cond = rng.integers(0, 6, cycles)
        w = w6[cond]
        th = np.tile(theta, (cycles, 1))
        res = truth.solve_series(w, th, truth.p_matrix(None, cycles))
        assert res.converged.all()
        y = truth.outputs_at(res.x, w, th, truth.p_matrix(None, cycles))
        y = y[:, [OUTPUT_NAMES.index(c) for c in CHANNELS]]
        y = y + rng.normal(0.0, 1.0, y.shape) * np.array([NOISE[c] for c in CHANNELS])
        frame = pd.DataFrame(y, columns=list(CHANNELS))
        frame.insert(0, "cycle", np.arange(1, cycles + 1))
        frame.insert(0, "unit", u)
        for j, name in enumerate(("alt", "Mach", "TRA", "T2")):
            frame[name] = w[:, j]
        frame["condition"] = cond + 1
        rows.append(frame)
    return pd.concat(rows, ignore_index=True)


#: the candidates of every adaptation in this module: one model (one compiled variant) for
#: all, each adaptation selecting among its own (``adapt(model=)``, ``prebuilt_groups``)
MODULE_CANDIDATES = (*CANDIDATES, "map_slope", "duct_loss", "cooling_flow")


@pytest.fixture(scope="module")
def candidate_model():
    return CandidateModel(build_groups(CHANNELS, MODULE_CANDIDATES), sens_outputs=CHANNELS)


@pytest.fixture(scope="module")
def shaped():
    return simulated_fleet([SHAPE], seed=1)


def test_noise_from_the_data_finds_the_simulated_levels():
    df = simulated_fleet(units=20, cycles=20, seed=3)
    table = noise_from_data(df, CHANNELS)
    assert list(table.index) == [1, 2, 3, 4, 5, 6]
    ratio = table / pd.Series(NOISE)[list(CHANNELS)]
    # about 30 degrees of freedom per condition: within +-35 %
    assert ratio.to_numpy().min() > 0.65 and ratio.to_numpy().max() < 1.35


def test_noise_needs_two_samples_of_an_engine_and_refuses_a_flat_channel():
    df = simulated_fleet(units=6, cycles=12, seed=4)
    flat = df.assign(P15=14.7)
    with pytest.raises(InputError, match="P15"):
        noise_from_data(flat, CHANNELS)
    one = df.groupby(["unit", "condition"]).head(1)
    with pytest.raises(InputError, match="no engine has two early-life samples"):
        noise_from_data(one, CHANNELS)


def test_a_missing_reading_counts_in_neither_the_noise_nor_its_degrees_of_freedom():
    df = simulated_fleet(units=6, cycles=12, seed=4)
    gap = df.copy()
    gap.loc[5, "T30"] = np.nan
    table = noise_from_data(gap, CHANNELS)
    np.testing.assert_allclose(table["T30"], noise_from_data(df.drop(index=5), CHANNELS)["T30"])
    others = [c for c in CHANNELS if c != "T30"]
    pd.testing.assert_frame_equal(table[others], noise_from_data(df, CHANNELS)[others])


def test_a_channel_written_to_a_coarse_resolution_keeps_its_rounding_noise():
    df = simulated_fleet(units=6, cycles=12, seed=5)
    df["P15"] = df["P15"].round(1)  # 0.1 psia: rounding std 0.029, more than the noise
    table = noise_from_data(df, CHANNELS)
    assert (table["P15"] >= 0.1 / np.sqrt(12) - 1e-12).all()


def test_each_samples_std_adds_the_models_own_error_to_the_noise():
    df = simulated_fleet(units=6, cycles=12, seed=6)
    noise_only, table = fleet_data(df, CHANNELS, model_error=0.0)
    np.testing.assert_allclose(noise_only.sigma, table.loc[noise_only.condition,
                                                           list(CHANNELS)].to_numpy())
    both, _ = fleet_data(df, CHANNELS, model_error=0.002)
    early = df[df["cycle"] <= 20]
    level = early.groupby("condition")[list(CHANNELS)].mean().loc[both.condition].to_numpy()
    np.testing.assert_allclose(both.sigma ** 2, noise_only.sigma ** 2 + (0.002 * level) ** 2)
    with pytest.raises(InputError, match="model error"):
        fleet_data(df, CHANNELS, model_error=-0.01)
    # measured data get the model's own error by default (0.1 %); a simulated fleet has none
    default, _ = fleet_data(df, CHANNELS)
    np.testing.assert_allclose(default.sigma ** 2,
                               noise_only.sigma ** 2 + (MODEL_ERROR * level) ** 2)
    assert MODEL_ERROR == 0.001


def test_fleet_fit_separates_the_shared_level_from_each_engines_health(candidate_model):
    """A fleet whose HPC efficiency is 1.5 % low in every engine: the shared design scaling
    takes the offset, the engines' own health stays near zero on average."""
    df = simulated_fleet(["design_scaling:component=HPC,eff=-0.015"], units=10, seed=2)
    data, _ = fleet_data(df, CHANNELS, model_error=0.0)
    groups = candidate_model.candidates
    sh = shared_of(groups, ["design_scaling_HPC"])
    fit = fit_fleet(candidate_model, data, sh)
    hpc = next(c for c in groups if c.name == "design_scaling_HPC")
    eff, flow = fit.phi[hpc.index]
    std = fit.std
    assert abs(eff + 0.015) < 3 * std[0] + 1e-3 and abs(flow) < 3 * std[1] + 1e-3
    assert abs(fit.delta[:, THETA_NAMES.index("HPC_eff_mod")].mean()) < 1e-3
    # without the shared parameter the offset lands in every engine's health
    own = fit_fleet(candidate_model, data, Shared.none())
    assert own.delta[:, THETA_NAMES.index("HPC_eff_mod")].mean() < -0.005
    # on one engine the two are the same residual: only the engines' prior tells them apart
    assert abs(fit.chi2_per_sample() - own.chi2_per_sample()) < 0.01
    assert fit.cost < own.cost - 5.0


def test_a_fit_whose_optimum_is_on_the_bounds_converges_to_it(candidate_model, shaped):
    """The levels alone cannot follow a map shape: their optimum lies on the bounds, with
    engines' health on the envelope too. The fit converges there (the relative decrease
    falls below its tolerance well inside the iteration cap) and the point it returns meets
    the bounded problem's optimality conditions (Karush-Kuhn-Tucker): the gradient of the
    free parameters vanishes and that of a parameter on a bound pushes out of the range.
    (Holding a parameter only when the step pushed it out released and clipped such
    parameters every other iteration: this fit stopped at the 40-iteration cap 1 % above
    its optimum.)"""
    from calibration.adaptation.fleet_fit import THETA_HI, THETA_LO, _normal_equations

    data, _ = fleet_data(shaped, CHANNELS, model_error=0.0)
    groups = candidate_model.candidates
    own = fit_fleet(candidate_model, data, Shared.none())
    sh = shared_of(groups, [c.name for c in groups if c.registry_name == "design_scaling"])
    fit = fit_fleet(candidate_model, data, sh, own.phi, own.delta, x0=own.x)
    assert fit.iterations < MAX_ITER // 2, fit.history
    b = fit.phi[sh.free]
    lo, hi = b <= sh.lower, b >= sh.upper
    assert (lo | hi).any() and ((fit.delta <= THETA_LO) | (fit.delta >= THETA_HI)).any()
    ev, e, ok = evaluate(candidate_model, data, fit.delta, fit.phi, True, fit.x)
    starts = np.searchsorted(data.unit, np.arange(data.n_units))
    _, gu, _, hbb, gb = _normal_equations(ev, e, ok, data.sigma, fit.delta, b, sh.free,
                                          sh.prior, fit.s_theta, starts)
    scale = np.sqrt(np.diag(hbb))  # gradient per unit of the parameter's curvature
    assert np.all(gb[lo] < 0) and np.all(gb[hi] > 0)
    assert np.all(np.abs(gb[~(lo | hi)]) < 0.05 * scale[~(lo | hi)]), gb / scale


def test_a_candidate_enters_on_the_out_of_sample_gain_and_the_worst_condition_is_reported():
    current = OutOfSample(10.0, chi2={1: 8.0, 2: 12.0, 3: 10.0})
    assert current.worst == 12.0
    assert enters(OutOfSample(9.0, chi2={1: 7.0, 2: 12.0, 3: 8.0}), current)
    small = 10.0 * (1.0 - MIN_GAIN / 2)
    assert not enters(OutOfSample(small, chi2={1: 8.0, 2: 11.9, 3: 10.0}), current)


def test_judging_fewer_than_one_candidate_is_refused_and_the_cli_defaults_are_the_librarys():
    import inspect
    import typing

    from calibration.measurement_noise import EARLY_CYCLES
    from cli.adapt import adapt as adapt_cli

    with pytest.raises(ValueError, match="judge"):
        select(None, None, [], judge=0)
    cli, lib = (inspect.signature(f).parameters for f in (adapt_cli, adapt))
    assert cli["judge"].default == TOP == lib["judge"].default
    assert cli["early_cycles"].default == EARLY_CYCLES == lib["early_cycles"].default
    # the help texts name the library's defaults, not a copy that drifts
    from calibration.adaptation.data import DEFAULT_CHANNELS
    from calibration.adaptation.groups import OPTIONAL_GROUPS, SENSOR_GROUP, STEADY_GROUPS

    hints = typing.get_type_hints(adapt_cli, include_extras=True)

    def help_of(name):
        return hints[name].__metadata__[0].help

    assert f"default: {','.join(DEFAULT_CHANNELS)})" in help_of("channels")
    assert f"default: {', '.join((*STEADY_GROUPS, SENSOR_GROUP))};" in help_of("candidates")
    assert f"also {', '.join(OPTIONAL_GROUPS)} when named" in help_of("candidates")


def test_adapt_refuses_what_it_cannot_fit_before_any_fit():
    """One line each, before the (long) selection starts: a channel the model does not
    compute, a reading that is not a number, a fleet too small to hold engines out, a
    judge below one."""
    df = simulated_fleet(units=3, cycles=6, seed=8)
    with pytest.raises(InputError, match="--channels: Ps31 not an output"):
        adapt(df.assign(Ps31=1.0), (*CHANNELS, "Ps31"), CANDIDATES)
    nan = df.copy()
    nan.loc[7, "T30"] = np.nan
    with pytest.raises(InputError, match=r"unit 2, cycle 2: column T30 is not a finite"):
        adapt(nan, CHANNELS, CANDIDATES)
    with pytest.raises(InputError, match="2 engine\\(s\\) .* 3 folds"):
        adapt(simulated_fleet(units=2, cycles=20, seed=8), CHANNELS, CANDIDATES)
    with pytest.raises(InputError, match="judge must be at least 1"):
        adapt(df, CHANNELS, CANDIDATES, judge=0)


def test_a_record_names_its_optional_candidates_and_is_strict_json(tmp_path):
    """``assess`` and the design-point benchmark rebuild a record's candidate groups: the
    optional ones (``duct_loss``, ...) among them; a chosen name no group has, or a chosen
    parameter without a value, is refused; a number that could not be computed is null."""
    rec = {"channels": list(CHANNELS),
           "selection": {"chosen": ["design_scaling_HPC", "duct_loss", "sensor_gain_P15"]},
           "parameters": [{"candidate": "design_scaling_HPC", "parameter": "eff",
                           "value": 0.0}]}
    names = {c.name for c in record_groups(rec, CHANNELS)}
    assert {"design_scaling_HPC", "duct_loss", "sensor_gain_P15"} <= names
    with pytest.raises(InputError, match="chosen candidate\\(s\\) no_such"):
        record_groups({**rec, "selection": {"chosen": ["no_such"]}}, CHANNELS)
    df = simulated_fleet(units=6, cycles=12, seed=4)
    with pytest.raises(InputError, match="no value of design_scaling_HPC.flow"):
        assess(df, rec)
    levels = CandidateModel(build_groups(CHANNELS, ["design_scaling"]), compiled=False)
    with pytest.raises(InputError, match="prebuilt model lacks chosen candidate\\(s\\) "
                                         "duct_loss, sensor_gain_P15"):
        assess(df, rec, model=levels)
    with pytest.raises(InputError, match="prebuilt model lacks candidate\\(s\\) nozzle_area$"):
        adapt(df, CHANNELS, ("design_scaling", "nozzle_area"), model=levels)
    out = write_adapted({"effects": [], "selection": {"worst": float("nan")}},
                        tmp_path / "a.json")
    assert json.loads(out.read_text())["selection"]["worst"] is None


def test_a_condition_the_model_cannot_evaluate_is_the_worst_not_left_out(monkeypatch):
    """A candidate under which no held-out sample of a condition converges predicts that
    condition worst of all: ``chi2_out`` infinite, so it cannot enter on the other
    conditions' lower error (the solves are stand-ins: only the bookkeeping is tested)."""
    from types import SimpleNamespace

    import calibration.adaptation.selection as selection

    data, _ = fleet_data(simulated_fleet(units=6, cycles=12, seed=4), CHANNELS, model_error=0)
    k = len(THETA_NAMES)

    def fake_fit(model, train, shared, phi0=None, delta0=None, **kw):
        return SimpleNamespace(delta=np.zeros((train.n_units, k)), phi=np.zeros(1),
                               iterations=3)

    def fake_evaluate(model, test, delta, phi, derivatives=False, x0=None):
        ok = np.full(len(test.y), test.condition[0] != 2)  # condition 2 never converges
        return SimpleNamespace(y=test.y + 0.1), np.ones_like(test.y), ok

    monkeypatch.setattr(selection, "fit_fleet", fake_fit)
    monkeypatch.setattr(selection, "evaluate", fake_evaluate)
    monkeypatch.setattr(selection, "mean_prediction_std",
                        lambda fit, ev, test, row, ok: np.ones(len(CHANNELS)))
    start = SimpleNamespace(phi=np.zeros(1), delta=np.zeros((data.n_units, k)), offsets=None)
    o = selection.condition_out(None, data, Shared.none(), start)
    assert np.isinf(o.chi2[2]) and np.isinf(o.worst) and np.isinf(o.chi2_out)
    assert o.unusable[2] == int((data.condition == 2).sum()) and o.unusable[1] == 0
    assert o.chi2[1] == 1.0 and o.iterations == {c: 3 for c in range(1, 7)}
    assert not enters(o, OutOfSample(50.0, chi2={1: 50.0}))


def test_adapt_names_a_map_shape_change_and_the_held_out_error_returns_to_the_noise(
        candidate_model, shaped):
    res = adapt(shaped, CHANNELS, CANDIDATES, model=candidate_model,
                model_error=0.0)
    sel = res.selection
    added = [c for c in sel.chosen if not c.startswith("design_scaling")]  # levels: always
    assert added and added[0] == "map_scaling_HPC"
    assert sel.after.chi2_out < 0.5 * sel.before.chi2_out
    assert sel.after.chi2_out < 1.5  # the noise: 1
    rec = res.record()
    assert rec["selection"]["chi2_engines_out"]["after"] < rec["selection"][
        "chi2_engines_out"]["before"]
    p = {(r["candidate"], r["parameter"]): r for r in rec["parameters"]}
    assert p[("map_scaling_HPC", "eff_1")]["value"] > 0.2
    assert all(np.isfinite(r["std"]) and r["std"] > 0 for r in rec["parameters"])


def test_adapt_names_a_flatter_fan_speed_line_where_the_corrected_speed_does_not_change(
        candidate_model):
    """C-MAPSS holds the corrected fan speed at one value in five of its six conditions, so a
    shape in corrected speed cannot tell them apart; the fan's working point still moves
    along its speed line as the bypass nozzle chokes. A fleet whose fan has flatter speed
    lines (``map_slope`` -0.4): the loop names the fan's slope, recovers it, and the held-out
    error returns to the noise. (The candidates are the levels, the slopes and the fan's
    nozzle, whose area also moves the fan's working point; the shapes in corrected speed
    are left out to keep the test's cost down: they cannot follow the five conditions at
    one corrected fan speed in any case.)"""
    names = ("design_scaling", "map_slope", "nozzle_area")
    fleet = simulated_fleet(["map_slope:component=fan,slope=-0.4"], units=8, cycles=12,
                            seed=11)
    res = adapt(fleet, CHANNELS, names, model=candidate_model, model_error=0.0, judge=2)
    sel = res.selection
    added = [c for c in sel.chosen if not c.startswith("design_scaling")]
    assert added and added[0] == "map_slope_fan", sel.chosen
    assert sel.after.chi2_out < 1.5 < sel.before.chi2_out
    p = {(r["candidate"], r["parameter"]): r for r in res.record()["parameters"]}
    slope = p[("map_slope_fan", "slope")]
    assert abs(slope["value"] + 0.4) < max(3 * slope["std"], 0.05), slope


def test_adapt_adds_nothing_to_a_fleet_the_model_already_explains(candidate_model):
    lines = []
    res = adapt(simulated_fleet(seed=7), CHANNELS, CANDIDATES, model=candidate_model,
                model_error=0.0, log=lines.append, judge=2)
    assert all(c.startswith("design_scaling") for c in res.selection.chosen)
    # one step, two candidates judged with each condition left out (--judge 2), recorded
    assert sum(1 for m in lines if m.startswith("  ")) == 2, lines
    rec = res.record()
    assert rec["data"]["judge"] == 2 and rec["selection"]["stopped"] == "no gain"
    assert rec["data"]["unit_list"] == list(range(1, 13)) and rec["data"]["seed"] == 0
    # every fit with a condition left out converged (none stopped at the iteration cap)
    its = rec["selection"]["iterations_condition_out"]["after"]
    assert sorted(its) == [1, 2, 3, 4, 5, 6] and 0 < max(its.values()) < MAX_ITER, its
    # with the right model every condition left out is predicted within a few of its own
    # std (the posterior's and the noise's; 42 conditions x channels)
    assert max(worst_z(res.selection.after).values()) < 4.0
    # the levels, always fitted, are zero within their uncertainty
    for p in res.record()["parameters"]:
        assert abs(p["value"]) < 3 * p["std"] + 1e-4, p


def test_the_adapted_model_round_trips_and_calibrate_records_it(tmp_path, candidate_model,
                                                                 shaped):
    # a record is all this needs: one candidate judged per step (--judge 1) keeps it short
    res = adapt(shaped.iloc[: 12 * 18 // 2], CHANNELS, CANDIDATES, model=candidate_model,
                model_error=0.0, judge=1)
    out = write_adapted(res.record(), tmp_path / "adapted.json")
    loaded = load_adapted(out)
    assert loaded.effects == res.effects()
    doc = json.loads(out.read_text())
    assert doc["format"] == "hyprog-adapted-model" and doc["data"]["units"] == 6
    # the record refitted to the same data from its file gives its own held-out errors
    fit, oos = assess(shaped.iloc[: 12 * 18 // 2], doc, model=candidate_model)
    rec = doc["selection"]
    for c, errors in rec["mean_error_pct_condition_out"]["after"].items():
        for ch, v in errors.items():
            assert abs(oos.mean_error_pct[int(c)][ch] - v) < 1e-3, (c, ch)
            assert oos.std_pct[int(c)][ch] == pytest.approx(
                rec["std_pct_condition_out"]["after"][c][ch], rel=1e-3)
    assert abs(fit.chi2_per_sample() - rec["chi2_in_sample"]["after"]) < 1e-3
    # the groups a record's candidates come from, every chosen candidate among them
    names = {c.name for c in record_groups(doc, CHANNELS)}
    assert set(rec["chosen"]) <= names
    assert names <= {c.name for c in candidate_model.candidates}
    # refused: not an adapted model, a bad specification
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "hyprog-adapted-model", "version": 1,
                               "effects": ["no_such_effect:x=1"]}))
    with pytest.raises(InputError, match=r"bad\.json: effects\[0\]"):
        load_adapted(bad)
    bad.write_text("{}")
    with pytest.raises(InputError, match="not an adapted model"):
        load_adapted(bad)
    # refused, as a request that would do nothing or cannot be applied: no effect, an effect
    # at its neutral sizes, a series effect, an effect twice
    for effects, message in (([], "holds no effect"),
                             (["customer_bleed:f0=0,f_alt=0"], "neutral default"),
                             (["dynamics:tau_spool=1"], "series effect"),
                             (["customer_bleed:f0=0.01", "customer_bleed:f0=0.02"],
                              "more than once")):
        bad.write_text(json.dumps({"format": "hyprog-adapted-model", "version": 1,
                                   "effects": effects}))
        with pytest.raises(InputError, match=rf"bad\.json: .*{message}"):
            load_adapted(bad)


def test_calibrate_with_model_effects_records_the_adapted_model(tmp_path):
    from cli.main import app
    from engine_model import datasets
    from tests.cli_checks import assert_user_error, cli_runner

    df, meta = datasets.read_dataset(TINY, units=[1])
    data = tmp_path / "fleet"
    datasets.write_parquet(df[df["cycle"] <= 2].reset_index(drop=True), data, meta)
    adapted = write_adapted({"effects": ["design_scaling:component=HPC,eff=-0.01"],
                             "data": {"path": "test"}}, tmp_path / "adapted.json")
    runner = cli_runner()
    r = runner.invoke(app, ["calibrate", str(data), "--out", str(tmp_path / "f"),
                            "--model-effects", str(adapted), "--quiet"])
    assert r.exit_code == 0, r.stderr
    cal = datasets.read_metadata(tmp_path / "f")["calibration"]
    assert cal["effects"] == ["design_scaling:component=HPC,eff=-0.01,flow=0"]  # canonical
    assert cal["model_effects"]["sha256"] == load_adapted(adapted).sha256
    # the model's HPC efficiency is 1 % lower, so the engine's own estimate rises by about 1 %
    plain = runner.invoke(app, ["calibrate", str(data), "--out", str(tmp_path / "g"),
                                "--params", "HPC_eff_mod,HPT_eff_mod,LPT_eff_mod", "--quiet"])
    shifted = runner.invoke(app, ["calibrate", str(data), "--out", str(tmp_path / "h"),
                                  "--params", "HPC_eff_mod,HPT_eff_mod,LPT_eff_mod",
                                  "--model-effects", str(adapted), "--quiet"])
    assert plain.exit_code == 0 and shifted.exit_code == 0, shifted.stderr
    a = datasets.read_dataset(tmp_path / "g")[0]["HPC_eff_mod_hat"].iloc[-1]
    b = datasets.read_dataset(tmp_path / "h")[0]["HPC_eff_mod_hat"].iloc[-1]
    assert 0.007 < b - a < 0.013
    missing = runner.invoke(app, ["calibrate", str(data), "--out", str(tmp_path / "x"),
                                  "--model-effects", str(tmp_path / "nope.json")])
    assert_user_error(missing, "nope.json", "cannot read the adapted model")
    assert not (tmp_path / "x").exists()


def test_adapt_cli_refuses_bad_input_in_one_line(tmp_path):
    from cli.main import app
    from tests.cli_checks import assert_user_error, cli_runner

    runner = cli_runner()
    r = runner.invoke(app, ["adapt", str(TINY), "--out", str(tmp_path / "a.json")])
    assert_user_error(r, "condition")  # the simulated fleet has no condition label
    r = runner.invoke(app, ["adapt", str(TINY), "--out", str(tmp_path / "a.json"),
                            "--candidates", "bleed"])
    assert_user_error(r, "unknown candidate(s) bleed")
    r = runner.invoke(app, ["adapt", str(TINY), "--out", str(tmp_path / "a.json"),
                            "--candidates", "map_scaling,map_scaling"])
    assert_user_error(r, "map_scaling listed twice")
    r = runner.invoke(app, ["adapt", str(TINY), "--out", str(tmp_path / "a.json"),
                            "--model-error", "0", "--model-error-shared"])
    assert_user_error(r, "--model-error-shared: the model error is 0")  # would do nothing
    assert not (tmp_path / "a.json").exists()


def test_pipeline_refuses_a_bad_adapted_model_before_any_stage(tmp_path):
    from cli.main import app
    from tests.cli_checks import assert_user_error, cli_runner

    bad = tmp_path / "adapted.json"
    bad.write_text(json.dumps({"format": "hyprog-adapted-model", "version": 2,
                               "effects": []}))
    r = cli_runner().invoke(app, ["pipeline", "--out", str(tmp_path / "run"),
                                  "--model-effects", str(bad)])
    assert_user_error(r, "adapted.json", "version 2")
    assert not (tmp_path / "run").exists()


def test_the_held_out_prediction_std_is_the_joint_posteriors(candidate_model, shaped):
    """The std of a held-out condition's mean prediction from the Schur blocks equals the
    one from the dense joint posterior (every engine's health and the shared parameters in
    one Gauss-Newton matrix, inverted whole); an engine the fit did not see has its prior."""
    from calibration.adaptation.fleet_fit import evaluate, mean_prediction_std

    data, _ = fleet_data(shaped[shaped["unit"] <= 5], CHANNELS, model_error=0.0)
    groups = candidate_model.candidates
    sh = shared_of(groups, ["design_scaling_HPC", "map_scaling_HPC"])
    held = data.condition == 4
    train, test = data.subset(~held), data.subset(held)
    fit = fit_fleet(candidate_model, train, sh)
    ev, _, ok = evaluate(candidate_model, train, fit.delta, fit.phi, derivatives=True)
    assert ok.all()
    k, p, U = len(THETA_NAMES), len(sh.free), train.n_units
    J = np.zeros((len(train.y), len(CHANNELS), U * k + p))
    for n, u in enumerate(train.unit):
        J[n, :, u * k:(u + 1) * k] = ev.d_theta[n]
        J[n, :, U * k:] = ev.d_phi[n][:, sh.free]
    Jw = (J / train.sigma[:, :, None]).reshape(-1, U * k + p)
    H = Jw.T @ Jw + np.diag(np.r_[np.full(U * k, 1 / fit.s_theta ** 2), 1 / sh.prior ** 2])
    cov = np.linalg.inv(H)
    # the test engines: all seen, but the last one is treated as unseen (its prior)
    engine = np.array([train.units.index(u) for u in test.units])
    engine[-1] = -1
    delta = np.where(engine[:, None] >= 0, fit.delta[np.maximum(engine, 0)], 0.0)
    evt, _, okt = evaluate(candidate_model, test, delta, fit.phi, derivatives=True)
    assert okt.all()
    got = mean_prediction_std(fit, evt, test, engine, okt)
    N = len(test.y)
    f = np.zeros((len(CHANNELS), U * k + p))
    own = np.zeros((len(CHANNELS), k))
    for n, u in enumerate(test.unit):
        f[:, U * k:] += evt.d_phi[n][:, sh.free] / N
        if engine[u] >= 0:
            f[:, engine[u] * k:(engine[u] + 1) * k] += evt.d_theta[n] / N
        else:
            own += evt.d_theta[n] / N
    var = np.einsum("mi,ij,mj->m", f, cov, f) + fit.s_theta ** 2 * np.sum(own ** 2, axis=1)
    want = np.sqrt(var + np.sum(test.sigma ** 2, axis=0) / N ** 2)
    np.testing.assert_allclose(got, want, rtol=1e-6)
    # the model's own error, part of each sample's sigma, is shared by the samples of the
    # condition: it adds its mean's square whole, not averaged away like the noise
    sd = 0.5 * test.sigma
    shared_error = mean_prediction_std(fit, evt, replace(test, model_sd=sd), engine, okt)
    np.testing.assert_allclose(shared_error ** 2 - got ** 2,
                               sd.mean(axis=0) ** 2 - np.sum(sd ** 2, axis=0) / N ** 2,
                               rtol=1e-6)


def worst_z(oos: OutOfSample) -> dict:
    """Per condition left out, the largest |mean error| / its std over the channels."""
    return {c: max(abs(oos.mean_error_pct[c][ch]) / oos.std_pct[c][ch] for ch in CHANNELS)
            for c in oos.std_pct}


def test_a_map_shape_the_fit_lacks_shows_as_held_out_errors_of_many_stds(candidate_model,
                                                                          shaped):
    """The levels alone on the fleet whose HPC loses efficiency at part power: every
    condition left out misses by many of its own stds (worst at condition 4 about 36;
    with the right model they stay within 2-3, test above)."""
    lacking = adapt(shaped, CHANNELS, ("design_scaling",), model=candidate_model,
                    model_error=0.0)
    assert worst_z(lacking.selection.after)[4] > 5.0
    rec = lacking.record()["selection"]["std_pct_condition_out"]
    assert set(rec["after"]) == set(range(1, 7)) == set(rec["before"])


def test_a_fitted_bleed_schedule_negative_at_the_ceiling_is_refused_before_writing():
    """The fit bounds ``f0`` and ``f_alt`` one by one; their combination is checked when the
    effects are written, as the loader checks it: an unloadable model is never written."""
    from calibration.adaptation.adapt import effect_specs

    groups = build_groups(("T30",), ["customer_bleed"])
    (c,) = groups

    def effects(f0, f_alt):
        phi = np.zeros(len(c.params))
        phi[list(c.params).index("f0")], phi[list(c.params).index("f_alt")] = f0, f_alt
        return effect_specs(groups, [c.name], phi)

    assert effects(0.0, 0.0046) == ["customer_bleed:f0=0,f_alt=0.0046"]
    with pytest.raises(InputError, match="cannot be written: customer_bleed:f0=0.01,"
                                         "f_alt=-0.005.*< 0"):
        effects(0.01, -0.005)


def test_design_point_losses_and_coolant_as_fleet_effects_and_what_the_fit_can_tell(
        candidate_model):
    """The opt-in design-point candidates (``duct_loss``, ``cooling_flow``) on a fleet whose
    bypass duct loses 0.5 % and whose burner 1 % more pressure, and whose HPT takes 1 % more
    coolant, in every engine. Fitted jointly with every engine's health: the bypass loss is
    identified (std below 0.1 %: ``P15`` sees it alone) and recovered; the burner's loss and
    the coolant are within three stds, and the fit says how little it can tell them from the
    engines' HPC and HPT health (stds of 0.4 % and 1.2 % on this fleet). Not defaults:
    ``adapt`` without
    ``--candidates`` leaves them out."""
    df = simulated_fleet(["duct_loss:d_bypass=0.005,d_burner=0.01", "cooling_flow:d_hpt=0.01"],
                         units=10, seed=3)
    data, _ = fleet_data(df, CHANNELS, model_error=0.0)
    groups = prebuilt_groups(candidate_model, ["duct_loss", "cooling_flow"])
    sh = shared_of(groups, ["duct_loss", "cooling_flow"])
    fit = fit_fleet(candidate_model, data, sh)
    truth = {"d_bypass": 0.005, "d_burner": 0.01, "d_hpt": 0.01}
    names = [q for c in groups for q in c.params]
    est = dict(zip(names, zip(fit.phi[sh.free], fit.std, strict=True), strict=True))
    for q, (v, s) in est.items():
        assert abs(v - truth.get(q, 0.0)) < 3 * s + 1e-4, (q, v, s)
    assert est["d_bypass"][1] < 1e-3
    assert est["d_burner"][1] > 2e-3 and est["d_hpt"][1] > 2e-3
    assert fit.chi2_per_sample() < 1.2  # the noise: 1
    assert not {"duct_loss", "cooling_flow"} & {c.name for c in build_groups(CHANNELS)}
