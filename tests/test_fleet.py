"""Fleet simulator: determinism, schema, degradation (EOL, t_s, health index), noise, presets,
h5 round trip, undeclared effects in the metadata, and the CLI."""

import json

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from cli.main import app
from engine_model import THETA_NAMES, W_NAMES, XS_NAMES, XV_NAMES, EngineModel, datasets
from engine_model.physics import health_index as hix
from engine_model.physics.effects import parse_effect_spec
from engine_model.simulator import degradation as dg
from engine_model.simulator import fleet, sensor_noise

runner = CliRunner()


@pytest.fixture(scope="module")
def tiny(model):
    df, meta, rep = fleet.simulate("tiny", seed=7, model=model)
    return df, meta, rep


def test_schema_and_bookkeeping(tiny):
    df, meta, rep = tiny
    expected = ["unit", "cycle", "t", "Fc", "hs", "RUL", *W_NAMES, *XS_NAMES, *XV_NAMES, "phi",
                *THETA_NAMES]
    assert list(df.columns) == expected
    assert df[list(expected)].notna().all().all()
    assert sorted(df.unit.unique()) == [1, 2, 3, 4]
    assert meta["dev_units"] == [1, 2, 3] and meta["test_units"] == [4]
    assert meta["sample_rate_hz"] == 0.1 and meta["effects"] == []
    for u, g in df.groupby("unit"):
        spec = fleet.get_preset("tiny").units[u - 1]
        eol, t_s = rep.eol[u], rep.t_s[u]
        assert spec.eol[0] <= eol <= spec.eol[1] and spec.t_s[0] <= t_s <= spec.t_s[1]
        assert g.cycle.max() == eol and (g.RUL == eol - g.cycle).all()
        assert (g.hs == (g.cycle < t_s)).all()
        assert (g.alt >= 10000.0 - 1e-6).all()  # recorded above 10,000 ft only
        assert np.all(np.diff(g.t.to_numpy())[np.diff(g.cycle.to_numpy()) == 0] == 10.0)
        # theta only ever degrades
        th = g.groupby("cycle")[list(THETA_NAMES)].first().to_numpy()
        assert np.all(np.diff(th, axis=0) <= 1e-15)


def test_same_seed_same_bytes(tmp_path, model):
    a, b = tmp_path / "a", tmp_path / "b"
    fleet.simulate("tiny", out=a, units=[2], seed=3, model=model)
    fleet.simulate("tiny", out=b, units=[2], seed=3, model=model)
    files = sorted(p.relative_to(a) for p in a.rglob("*.parquet"))
    assert files and all((a / f).read_bytes() == (b / f).read_bytes() for f in files)
    c = tmp_path / "c"
    fleet.simulate("tiny", out=c, units=[2], seed=4, model=model)
    assert (a / files[0]).read_bytes() != (c / files[0]).read_bytes()


def test_unit_does_not_depend_on_other_units(tiny, model):
    df, _, _ = tiny
    one, _, _ = fleet.simulate("tiny", units=[3], seed=7, model=model)
    pd.testing.assert_frame_equal(df[df.unit == 3].reset_index(drop=True), one)


def test_outputs_are_the_model_at_the_true_theta(tiny, model):
    """Noise-free channels (virtual sensors) equal the model at the recorded w and theta."""
    df, _, _ = tiny
    rows = df.sample(50, random_state=0)
    y = model.evaluate(rows[list(W_NAMES)].to_numpy(), theta=rows[list(THETA_NAMES)].to_numpy())
    # rtol 1e-8 of each channel, and atol 1e-6 for stall margins [%] that sit near zero at
    # flight idle (the simulator's warm-started series and this fresh solve agree to ~1e-8)
    np.testing.assert_allclose(rows[list(XV_NAMES)].to_numpy(), y[list(XV_NAMES)].to_numpy(),
                               rtol=1e-8, atol=1e-6)
    # measured channels carry noise of the documented size
    rel = rows[list(XS_NAMES)].to_numpy() / y[list(XS_NAMES)].to_numpy() - 1.0
    sig = np.array([sensor_noise.SIGMA_REL[c] for c in XS_NAMES])
    assert np.all(np.abs(rel) < 5 * sig)


def test_noise_has_the_documented_standard_deviation():
    n = 20000
    df = pd.DataFrame({c: np.full(n, 100.0) for c in XS_NAMES})
    df["P45"] = 5.0
    out = sensor_noise.add_noise(df, np.random.default_rng(0))
    rel_std = (out[list(XS_NAMES)] / 100.0 - 1.0).std()
    for c in XS_NAMES:
        assert rel_std[c] == pytest.approx(sensor_noise.SIGMA_REL[c], rel=0.03)
    assert (out["P45"] == 5.0).all()  # virtual sensors stay noise-free
    same = sensor_noise.add_noise(df, np.random.default_rng(0))
    pd.testing.assert_frame_equal(out, same)


@pytest.mark.parametrize("mode", list(dg.MODES))
def test_every_failure_mode_reaches_the_limit_at_eol(model, mode):
    hi_fn = hix.HealthIndex(model)
    h = dg.simulate_health(model, mode, (40, 60), (10, 20), np.random.default_rng(1),
                           hi_fn=hi_fn)
    assert 40 <= h.eol <= 60 and 10 <= h.t_s <= 20
    assert abs(h.hi[-1]) < 1e-6 and np.all(h.hi[:-1] > 0) and np.all(np.diff(h.hi) < 0)
    assert 0.8 < h.hi[0] <= 1.0  # initial wear: about 10 % of the health index
    # the mode's parameters carry the abnormal degradation
    lost = -h.theta[-1] - (-h.theta[h.t_s - 2])
    top = THETA_NAMES[int(np.argmax(lost))]
    assert top in dg.MODES[mode]


def test_health_index_definition(model):
    hi_fn = hix.HealthIndex(model)
    assert hi_fn(np.zeros(10))[0] == pytest.approx(1.0)
    th = np.zeros(10)
    th[THETA_NAMES.index("HPT_eff_mod")] = -0.02
    c = hi_fn.components(th)
    m = hix.reference_margins(model, th)
    assert c["EGT"][0] == pytest.approx((hi_fn.t48_lim - m["T48"][0]) / hix.EGT_MARGIN_DEGR)
    assert hi_fn(th)[0] == pytest.approx(min(v[0] for v in c.values()))


def test_harder_missions_wear_faster(model):
    hi_fn = hix.HealthIndex(model)
    mild = dg.simulate_health(model, "HPT", (30, 30), (10, 10), np.random.default_rng(5),
                              severity=np.full(30, 0.8), hi_fn=hi_fn)
    hard = dg.simulate_health(model, "HPT", (30, 30), (10, 10), np.random.default_rng(5),
                              severity=np.full(30, 1.2), hi_fn=hi_fn)
    # same draws: normal wear per cycle scales with severity
    d_mild = mild.theta[5] - mild.theta[0]
    d_hard = hard.theta[5] - hard.theta[0]
    np.testing.assert_allclose(d_hard, 1.5 * d_mild, rtol=1e-9)


def test_ds02_preset_shape():
    p = fleet.get_preset("ds02")
    units = {u.unit: u for u in p.units}
    assert sorted(units) == [2, 5, 10, 11, 14, 15, 16, 18, 20]
    assert [u.unit for u in p.units if u.split == "test"] == [11, 14, 15]
    assert {units[u].mode for u in (2, 5, 10)} == {"HPT"}
    assert {units[u].mode for u in (11, 14, 15, 16, 18, 20)} == {"HPT+LPT"}
    assert all(59 <= u.eol[0] <= u.eol[1] <= 89 and 16 <= u.t_s[0] <= 36 for u in p.units)
    # units 14 and 15 fly shorter, lower flights than the training units
    def mean_flight(u):
        fl = fleet._flights(units[u], 10, 1, 2, 0.1, "all")
        return np.mean([f.duration_h for f in fl]), np.mean([f.w[:, 0].max() for f in fl])
    d2, a2 = mean_flight(2)
    for u in (14, 15):
        d, a = mean_flight(u)
        assert d < d2 and a < a2


def test_undeclared_effect_is_recorded_only_in_metadata(tmp_path, model):
    eff = parse_effect_spec("customer_bleed:f0=0.02")
    truth = EngineModel(design=model.design, effects=[eff], compiled=False)
    out, rep = fleet.simulate("tiny", out=tmp_path / "bleed", units=[1], seed=7,
                              effects=[eff], model=truth)
    df, meta = datasets.read_dataset(out)
    assert meta["effects"] == [{"name": "customer_bleed", "params": {"f0": 0.02, "f_alt": 0.0}}]
    assert not any("bleed" in c for c in df.columns)  # nothing in the table gives it away
    clean, _, _ = fleet.simulate("tiny", units=[1], seed=7, model=model)
    # same flights and health, the bleed makes the engine burn more fuel
    assert (df.Wf.to_numpy() > clean.Wf.to_numpy()).mean() > 0.99


def test_series_effect_lags_the_truth(model):
    dyn = parse_effect_spec("dynamics:tau_spool=2,tau_thermal=120")
    lagged, meta, _ = fleet.simulate("tiny", units=[1], seed=7, rate_hz=1.0, model=model,
                                     effects=[dyn], noise_scale=0.0)
    clean, _, _ = fleet.simulate("tiny", units=[1], seed=7, rate_hz=1.0, model=model,
                                 noise_scale=0.0)
    d = (lagged.T48 - clean.T48).abs()
    assert d.max() > 1.0  # visible transient lag
    assert lagged.P2.equals(clean.P2)  # not a lagged channel
    assert meta["effects"][0]["name"] == "dynamics"


def test_a_sensor_fault_does_not_change_the_engines_health_index():
    """The margins are the engine's stations: a biased T48 reading moves neither the EGT
    margin nor, through it, the wear the simulator solves for."""
    clean = EngineModel(compiled=False)
    biased = EngineModel(effects=[parse_effect_spec("sensor_bias:channel=T48,gain=0.02")],
                         compiled=False)
    theta = np.zeros((2, len(THETA_NAMES)))
    theta[1, THETA_NAMES.index("HPT_eff_mod")] = -0.02
    np.testing.assert_allclose(hix.HealthIndex(biased)(theta), hix.HealthIndex(clean)(theta),
                               rtol=1e-12)


def test_lagged_pressures_stay_consistent_and_a_dropped_sample_does_not_leak(model):
    """Every station pressure lags with the spools, so they keep their order (P40 < P30,
    Ps30 < P30) through a transient; a sample that did not converge is dropped before the lag
    runs, so its outputs (NaN here) reach no kept sample."""
    dyn = parse_effect_spec("dynamics:tau_spool=4,tau_thermal=120")
    lagged, _, _ = fleet.simulate("tiny", units=[1], seed=7, rate_hz=1.0, model=model,
                                  effects=[dyn], noise_scale=0.0)
    assert (lagged.P40 < lagged.P30).all() and (lagged.Ps30 < lagged.P30).all()

    class OneFailure:  # the model, with sample 30 reported unconverged and NaN
        def __getattr__(self, name):
            return getattr(model, name)

        def solve_series(self, w, theta, p=None):
            res = model.solve_series(w, theta, p)
            res.converged[30] = False
            res.x[30] = np.nan
            return res

    with pytest.warns(UserWarning, match="1 samples did not converge"):
        df, _, _ = fleet.simulate("tiny", units=[1], seed=7, rate_hz=1.0, model=OneFailure(),
                                  effects=[dyn], noise_scale=0.0)
    assert len(df) == len(lagged) - 1 and np.isfinite(df[list(XS_NAMES)].to_numpy()).all()


def test_h5_round_trip_of_a_simulated_fleet(tmp_path, tiny):
    df, meta, _ = tiny
    path = datasets.write_ncmapss_h5(df, tmp_path / "tiny.h5", meta)
    back, meta2 = datasets.read_dataset(path)
    cols = [c for c in df.columns if c in back.columns]
    assert set(XS_NAMES) <= set(cols) and set(THETA_NAMES) <= set(cols)
    pd.testing.assert_frame_equal(back[cols].reset_index(drop=True),
                                  df[cols].reset_index(drop=True), check_dtype=False,
                                  rtol=1e-12)


def test_cli_simulate_info_effects(tmp_path):
    out = tmp_path / "fleet"
    r = runner.invoke(app, ["simulate", "--preset", "tiny", "--units", "4", "--out", str(out),
                            "--seed", "2", "--json"])
    assert r.exit_code == 0, r.output
    rep = json.loads(r.stdout)
    assert rep["units"]["4"]["rows"] > 0 and rep["units"]["4"]["dropped"] == 0
    r = runner.invoke(app, ["data", "info", str(out), "--json"])
    assert r.exit_code == 0, r.output
    info = json.loads(r.stdout)
    assert info["totals"]["units"] == 1 and info["units"][0]["eol"] == rep["units"]["4"]["eol"]
    r = runner.invoke(app, ["effects", "--json"])
    lib = {e["name"]: e for e in json.loads(r.stdout)}
    assert {"customer_bleed", "hp_offtake", "reynolds", "inlet_loss", "nozzle_area",
            "sensor_bias", "sensor_drift", "dynamics"} <= set(lib)
    assert lib["customer_bleed"]["parameters"][0]["unit"] == "-"


@pytest.mark.parametrize("args, msg", [
    (["--effect", "warp_drive"], "unknown effect 'warp_drive'"),
    # a request that would inject nothing (issue 31): refused, naming the typical sizes
    (["--effect", "customer_bleed"], "give its size, e.g. customer_bleed:f0=0.015"),
    (["--effect", "customer_bleed:f0=0,f_alt=0"], "neutral default"),
    (["--units", "1,x"], "--units 1,x"),
    (["--units", "9"], "no unit 9"),
    (["--rate", "0.3"], "rate_hz 0.3"),
    (["--preset", "ds99"], "unknown preset"),
    (["--format", "csv"], "'csv' is not one of 'parquet', 'h5'"),
])
def test_cli_simulate_bad_input(tmp_path, args, msg):
    out = tmp_path / "x"
    r = runner.invoke(app, ["simulate", "--out", str(out), *args])
    assert r.exit_code == 2
    assert r.stderr.startswith("error: ") and msg in r.stderr and len(r.stderr.splitlines()) == 1
    assert not out.exists()


def test_committed_sample_is_what_the_simulator_makes(model):
    """data_samples/tiny is `hyprog simulate --preset tiny --seed 0`; if the physics changes,
    regenerate it with that command."""
    from tests.conftest import REPO

    df, meta = datasets.read_dataset(REPO / "data_samples" / "tiny")
    assert meta["preset"] == "tiny" and meta["seed"] == 0
    fresh, _, _ = fleet.simulate("tiny", seed=0, model=model)
    pd.testing.assert_frame_equal(df.reset_index(drop=True), fresh, check_dtype=False,
                                  rtol=1e-9)


def test_study_preset_draws_another_fleet_per_seed(model):
    """``ds02-study`` (issue 30): 24 development and 6 test units, end of life and onset
    drawn per seed within the documented ranges."""
    p = fleet.get_preset("ds02-study")
    assert [u.split for u in p.units].count("test") == 6 and len(p.units) == 30
    assert {u.mode for u in p.units} == {"HPT", "HPT+LPT"}
    eols = []
    for seed in (0, 1, 2):
        _, _, rep = fleet.simulate("ds02-study", units=[3], seed=seed, rate_hz=0.01,
                                     model=model)
        assert 55 <= rep.eol[3] <= 95 and 14 <= rep.t_s[3] < rep.eol[3]
        eols.append((rep.eol[3], rep.t_s[3]))
    assert len(set(eols)) > 1
