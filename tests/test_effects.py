"""The effect library: neutral at defaults, the documented signature table, the sensor effects
touch only their channel, user-registered effects, spec parsing, the dynamics lag."""

import numpy as np
import pandas as pd
import pytest

from engine_model import OUTPUT_NAMES, XS_NAMES, EngineModel
from engine_model.physics.bleed_schedule import FixedOpening
from engine_model.physics.effect_library import Dynamics
from engine_model.physics.effects import (
    Effect,
    EffectSpecError,
    Param,
    describe_effects,
    effect_from_dict,
    parse_effect_spec,
    register,
    registry,
    unregister,
)
from engine_model.validation import InputError
from tests.conftest import w_rows

POINTS = {"SLS": (0.0, 0.0, 100.0), "CRZ": (35000.0, 0.8, 80.0)}
W = w_rows(list(POINTS.values()))
STEADY = sorted(n for n, c in registry().items() if not c.series)


def _instance(cls):
    if "channel" in cls.options:
        return cls(channel="T48")
    return cls(component="HPC") if "component" in cls.options else cls()


def _typical(cls):
    """Parameter vector at the effect's realistic size (context ``cycle`` = 20, an offset
    without a typical size = 5 channel units)."""
    vals = []
    for q in cls.params:
        if q.typical is not None:
            vals.append(q.typical)
        elif q.name == "cycle":
            vals.append(20.0)
        elif q.name == "offset":
            vals.append(5.0)
        else:
            vals.append(q.default)
    return np.array(vals)


@pytest.fixture(scope="module")
def effect_runs(model):
    """For every steady effect: outputs at its defaults and at its typical size. One model
    carries every steady effect (one symbolic build instead of one per effect); an effect at
    its typical size has every other at its defaults, where each is neutral (the test
    below: all at their defaults give the base model's outputs to 1e-9)."""
    insts = [_instance(registry()[name]) for name in STEADY]
    m = EngineModel(design=model.design, effects=insts, compiled=False)
    p0 = np.asarray(m.p_default, float)
    y0 = m.evaluate(W, p=p0)
    assert y0["converged"].all()
    y0 = y0[list(OUTPUT_NAMES)].astype(float)
    runs = {}
    for name, inst in zip(STEADY, insts, strict=True):
        cls = registry()[name]
        p = p0.copy()
        p[[m.param_names.index(f"{inst.name}.{q.name}") for q in cls.params]] = _typical(cls)
        y1 = m.evaluate(W, p=p)
        assert y1["converged"].all(), name
        runs[name] = (inst, y0, y1[list(OUTPUT_NAMES)].astype(float))
    return runs


def test_every_effect_is_neutral_at_its_defaults(model, effect_runs):
    base = model.evaluate(W)[list(OUTPUT_NAMES)].astype(float)
    _, y0, _ = next(iter(effect_runs.values()))  # every steady effect, all at its defaults
    np.testing.assert_allclose(y0.to_numpy(), base.to_numpy(), rtol=1e-9,
                               err_msg=", ".join(effect_runs))


@pytest.mark.parametrize("name", STEADY)
def test_signature_table(effect_runs, name):
    cls, y0, y1 = effect_runs[name]  # the instance: a component's moves are its own
    rel = (y1 - y0) / y0.abs()
    assert set(cls.signature) == set(POINTS)
    for i, label in enumerate(POINTS):
        for ch, sign in cls.signature[label].items():
            if ch == "<channel>":
                assert rel.iloc[i]["T48"] > 1e-6, (name, label)
            elif ch == "<others>":
                others = rel.iloc[i].drop("T48")
                assert (others.abs() < 1e-9).all(), (name, label, others[others.abs() >= 1e-9])
            elif sign == 0:
                assert abs(rel.iloc[i][ch]) < 1e-9, (name, label, ch)
            else:
                assert np.sign(rel.iloc[i][ch]) == sign and abs(rel.iloc[i][ch]) > 1e-5, (
                    name, label, ch, rel.iloc[i][ch])
    # the measured channels that move by more than 0.1 % at either point are exactly the
    # ones the effect declares it moves
    big = (rel[list(XS_NAMES)].abs() > 1e-3).any(axis=0)
    moved = set(big.index[big.to_numpy()])
    declared = {"T48" if m == "<channel>" else m for m in cls.moves}
    assert moved == declared, (name, moved ^ declared)


def test_customer_bleed_magnitude_is_physical(effect_runs):
    """1.5 % of core flow bled at HPC exit costs of the order of 1-3 % fuel at fixed fan
    speed (Walsh & Fletcher ch. 5: SFC penalty ~1-2 % per % of HP bleed)."""
    _, y0, y1 = effect_runs["customer_bleed"]
    dwf = (y1["Wf"] / y0["Wf"] - 1.0).to_numpy()
    assert np.all((dwf > 0.005) & (dwf < 0.05))


def test_customer_bleed_schedule_starts_at_sea_level(model):
    """The bleed fraction ``f0 + f_alt max(alt, 0)/10,000 ft``: below sea level the sea-level
    fraction holds (so the FD002 adaptation's ``f0 = 0`` never adds air), above it the
    schedule grows with altitude. ``p = (f0, f_alt)``."""
    m = EngineModel(design=model.design, effects=[parse_effect_spec("customer_bleed")],
                    compiled=False)
    w = w_rows([(-1500, 0.0, 90), (0, 0.0, 90), (20000, 0.6, 90)])
    flat, sched = m.evaluate(w, p=[0.01, 0.0]), m.evaluate(w, p=[0.01, 0.004])
    for c in ("Wf", "T48", "P30"):
        np.testing.assert_allclose(sched[c].iloc[:2], flat[c].iloc[:2], rtol=1e-12, err_msg=c)
    assert sched["Wf"].iloc[2] > flat["Wf"].iloc[2] * 1.001  # 0.8 % more bleed at 20,000 ft
    none = m.evaluate(w[:1], p=[0.0, 0.0])
    below = m.evaluate(w[:1], p=[0.0, 0.0046])  # the adapted FD002 model's schedule
    np.testing.assert_allclose(below["Wf"], none["Wf"], rtol=1e-12)


def test_reynolds_grows_with_altitude(model):
    m = EngineModel(design=model.design, effects=[parse_effect_spec("reynolds")],
                    compiled=False)
    w = w_rows([(0, 0.0, 90), (15000, 0.6, 90), (30000, 0.8, 90), (40000, 0.8, 90)])
    d = (m.evaluate(w, p=[0.05, 0.5])["T48"] - m.evaluate(w, p=[0.0, 0.5])["T48"]).to_numpy()
    # sea level at part power: small (component inlets a little below design pressure)
    assert abs(d[0]) < 0.1 * d[-1] and np.all(np.diff(d) > 0)


def test_sensor_drift_grows_with_cycle(model):
    m = EngineModel(design=model.design,
                    effects=[parse_effect_spec("sensor_drift:channel=P30,rate=1e-3")],
                    compiled=False)
    w = w_rows([(0, 0, 100)] * 3)
    p = m.effects.p_matrix(3, context={"cycle": np.array([0.0, 10.0, 20.0])})
    y = m.evaluate(w, p=p)["P30"].to_numpy()
    np.testing.assert_allclose(y / y[0], [1.0, 1.01, 1.02], rtol=1e-12)
    assert m.effects.estimable == ("sensor_drift_P30.rate",)


def test_user_registered_effect(model):
    class FanFaceBias(Effect):
        name = "test_t2_offset_p2"
        params = (Param("dP", "psia", 0.0, "offset on P2", 0.1, (0.0, 1.0)),)

        def apply(self, hook, value, p, ctx):
            return value + p["dP"] if hook == "sensor:P2" else value

    register(FanFaceBias)
    try:
        e = parse_effect_spec("test_t2_offset_p2:dP=0.25")
        m = EngineModel(design=model.design, effects=[e], compiled=False)
        w = w_rows([(0, 0, 100)])
        assert m.evaluate(w)["P2"].iloc[0] == pytest.approx(
            model.evaluate(w)["P2"].iloc[0] + 0.25, abs=1e-9)
        assert "test_t2_offset_p2" in [d["name"] for d in describe_effects()]
    finally:
        unregister("test_t2_offset_p2")
    assert "test_t2_offset_p2" not in registry()


def test_vbv_hook_sets_the_booster_bleed(model):
    """An effect that rewrites ``W_vbv`` (as benchmarks/vbv_schedule_audit.py does to hold the
    valves at a fixed opening) moves booster air into the bypass: the HPC gets W22 - W_vbv."""
    m = EngineModel(design=model.design, effects=[FixedOpening()], compiled=False)
    w = w_rows([(0, 0, 100), (20000, 0.7, 100)])
    for f in (0.0, 0.04):
        ev = m.evaluate(w, p=np.full((2, 1), f))
        assert ev.converged.all()
        np.testing.assert_allclose(ev.W25, (1.0 - f) * ev.W22, rtol=1e-9)
    base = model.evaluate(w)
    np.testing.assert_allclose(base.W25, base.W22, rtol=1e-9)  # the schedule is shut here
    np.testing.assert_allclose(m.evaluate(w, p=np.zeros((2, 1))).SmLPC, base.SmLPC, rtol=1e-7)
    # bleeding the booster lowers its working line: more stall margin
    assert np.all(m.evaluate(w, p=np.full((2, 1), 0.04)).SmLPC > base.SmLPC)


def test_spec_round_trip_and_errors():
    e = parse_effect_spec("sensor_bias:channel=T50,offset=3,gain=0.01")
    assert e.name == "sensor_bias_T50" and e.values == {"offset": 3.0, "gain": 0.01}
    assert effect_from_dict(e.to_dict()).values == e.values
    assert parse_effect_spec(e.spec()).values == e.values
    for bad, msg in [("nope", "unknown effect"), ("customer_bleed:f9=1", "no parameter"),
                     ("customer_bleed:f0=abc", "must be a number"),
                     ("sensor_bias:offset=1", "option 'channel' is required"),
                     ("sensor_bias:channel=XYZ", "unknown channel"),
                     ("customer_bleed:f0", "not param=value")]:
        with pytest.raises(EffectSpecError, match=msg):
            parse_effect_spec(bad)
    with pytest.raises(InputError, match="unknown effect"):  # a user's input error
        parse_effect_spec("nope")


def test_dynamics_first_order_lag_is_exact():
    tau = 5.0
    t = np.arange(0.0, 60.0, 2.0)
    u = np.where(t < 10.0, 1.0, 3.0)  # a step between t = 8 and t = 10 (linear ramp)
    y = Dynamics.lag(u[:, None], t, tau)[:, 0]
    # analytic response after the ramp, from the fine-grid solution of tau y' = u - y
    tf = np.arange(0.0, 60.0, 1e-3)
    uf = np.interp(tf, t, u)
    yf = np.empty_like(tf)
    yf[0] = 1.0
    a = np.exp(-1e-3 / tau)
    for k in range(1, len(tf)):  # exact for piecewise-constant steps of 1 ms: O(1e-4) error
        yf[k] = a * yf[k - 1] + (1 - a) * 0.5 * (uf[k] + uf[k - 1])
    np.testing.assert_allclose(y, np.interp(t, tf, yf), atol=1e-5)
    # non-uniform sampling gives the same answer at common times
    t2 = np.concatenate([t[:10], t[10:] + 0.5])
    assert Dynamics.lag(u[:, None], t2, tau)[9, 0] == pytest.approx(y[9])


def test_dynamics_on_a_flight_lags_spools_and_temperatures():
    t = np.arange(0.0, 600.0, 1.0)
    step = (t >= 100).astype(float)
    df = pd.DataFrame({"t": t, "Nc": 9000 + 500 * step, "T48": 1900 + 100 * step,
                       "P2": 14.0 + step})
    e = parse_effect_spec("dynamics:tau_spool=2,tau_thermal=60")
    out = e.apply_series(df)
    assert out["P2"].equals(df["P2"])  # not a spool channel: untouched
    k = 100 + 60  # one thermal time constant after the step
    assert (out["T48"][k] - 1900) / 100 == pytest.approx(1 - np.exp(-60 / 60), abs=0.01)
    assert (out["Nc"][102] - 9000) / 500 == pytest.approx(1 - np.exp(-2 / 2), abs=0.15)
    assert out["Nc"].iloc[-1] == pytest.approx(9500, abs=1e-6)
    # every station pressure follows the spools: they lag together and keep their order
    # (only P30 and P50 lagged before, and the burner exit rose above its inlet)
    df = pd.DataFrame({"t": t, "P30": 300 + 200 * step, "P40": 288 + 192 * step,
                       "Ps30": 280 + 186 * step, "P2": 14.0 + 0 * step})
    out = e.apply_series(df)
    assert (out["P40"] < out["P30"]).all() and (out["Ps30"] < out["P30"]).all()


def test_a_flatter_fan_speed_line_holds_the_pressure_ratio_at_cruise(model):
    """At SLS full power the fan runs at its design flow coefficient and nothing moves; at
    cruise its working point lies nearer choke (choked bypass nozzle), where a flatter speed
    line keeps more of the pressure ratio. Only the three compressors have speed lines. The
    surge line is where the stall flow coefficient is, away from the design's: a flatter line
    rises less to it, so the fan's stall margin shrinks even at SLS."""
    m = EngineModel(design=model.design,
                    effects=[parse_effect_spec("map_slope:component=fan")], compiled=False)
    w = w_rows([(0.0, 0.0, 100.0), (35000.0, 0.8, 100.0)])
    y0 = m.evaluate(w, p=np.zeros(1))
    y1 = m.evaluate(w, p=np.array([-0.3]))
    rel = ((y1[list(OUTPUT_NAMES)] - y0[list(OUTPUT_NAMES)]) / y0[list(OUTPUT_NAMES)].abs())
    assert rel.iloc[0][list(XS_NAMES)].abs().max() < 1e-9
    assert y1["SmFan"].iloc[0] < y0["SmFan"].iloc[0] - 1.0
    fpr0, fpr1 = (y["P15"].iloc[1] / y["P2"].iloc[1] for y in (y0, y1))
    assert fpr1 > fpr0 * 1.002
    assert abs(rel.iloc[1]["Nf"]) < 1e-9  # the controller holds the corrected fan speed
    for spec in ("map_slope", "map_slope:component=HPT"):
        with pytest.raises(EffectSpecError, match="component"):
            parse_effect_spec(spec)


def test_map_scaling_is_a_shape_in_corrected_speed(model):
    """At the design corrected speed (SLS, full power) the map is right and nothing moves; at
    part power a positive eff_1 lowers the HPC's efficiency: T48 rises. A component is
    required and must be one of the five."""
    m = EngineModel(design=model.design,
                    effects=[parse_effect_spec("map_scaling:component=HPC")], compiled=False)
    w = w_rows([(0.0, 0.0, 100.0), (0.0, 0.0, 60.0)])
    y0 = m.evaluate(w, p=np.zeros(4))
    y1 = m.evaluate(w, p=np.array([0.05, 0.0, 0.0, 0.0]))
    rel = ((y1[list(OUTPUT_NAMES)] - y0[list(OUTPUT_NAMES)]) / y0[list(OUTPUT_NAMES)].abs())
    assert rel.iloc[0].abs().max() < 1e-9
    assert rel.iloc[1]["T48"] > 1e-4
    for spec in ("map_scaling", "map_scaling:component=HPX"):
        with pytest.raises(EffectSpecError, match="component"):
            parse_effect_spec(spec)


def test_pressure_ratio_scaler_scales_the_head_at_a_map_point(model):
    """At one map point the scaler multiplies the isentropic head and the work by 1 + pr_mod
    and leaves the flow and the efficiency as they are; the surge line scales with it."""
    from engine_model.physics import components

    fan = model.design.fan
    base = components.compressor(fan, 288.15, 101325.0, 0.95, 0.3)
    up = components.compressor(fan, 288.15, 101325.0, 0.95, 0.3, pr_mod=0.02)
    for k in ("Wc", "W", "eta"):
        assert float(up[k]) == pytest.approx(float(base[k]), rel=1e-12)
    assert float(up["dh"]) == pytest.approx(1.02 * float(base["dh"]), rel=1e-12)
    assert float(up["PR"]) > float(base["PR"])
    assert float(up["PR_surge"]) > float(base["PR_surge"])
    # zero is the map as designed, bit for bit
    same = components.compressor(fan, 288.15, 101325.0, 0.95, 0.3, pr_mod=0.0)
    assert all(float(same[k]) == float(base[k]) for k in base)


def test_map_pressure_ratio_level_and_shape(model):
    """The shape terms are zero at the design corrected speed (SLS full power: nothing
    moves); the level lowers the fan's pressure ratio at the held corrected fan speed."""
    m = EngineModel(design=model.design,
                    effects=[parse_effect_spec("map_pressure_ratio:component=fan")],
                    compiled=False)
    w = w_rows([(0.0, 0.0, 100.0), (35000.0, 0.8, 80.0)])
    y0 = m.evaluate(w, p=np.zeros(3))
    shape = m.evaluate(w, p=np.array([0.0, 0.05, 0.2]))
    rel = (shape[list(XS_NAMES)] - y0[list(XS_NAMES)]) / y0[list(XS_NAMES)].abs()
    assert rel.iloc[0].abs().max() < 1e-9
    assert rel.iloc[1].abs().max() > 1e-4
    level = m.evaluate(w, p=np.array([-0.02, 0.0, 0.0]))
    for i in range(2):
        assert level["P15"].iloc[i] / level["P2"].iloc[i] < y0["P15"].iloc[i] / y0["P2"].iloc[i]
        assert level["Nf"].iloc[i] == pytest.approx(y0["Nf"].iloc[i], rel=1e-9)
    for spec in ("map_pressure_ratio", "map_pressure_ratio:component=HPT",
                 "map_pressure_ratio:component=fan,pr_0=0.2"):
        with pytest.raises(EffectSpecError):
            parse_effect_spec(spec)
