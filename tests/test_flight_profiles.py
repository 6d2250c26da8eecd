"""Flight profiles: reproducibility, flight classes, recording, and the physics of the traces."""


import numpy as np
import pytest

from engine_model.physics.atmosphere import t2_from_flight
from engine_model.simulator import flight_profiles as fp
from engine_model.validation import InputError, check_w

CLASSES = (1, 2, 3)


@pytest.fixture(scope="module")
def pools():
    return {Fc: fp.route_pool(Fc, 30, seed=10 + Fc) for Fc in CLASSES}


@pytest.fixture(scope="module")
def whole_flights(pools):
    """Three whole flights per class at 1 Hz, one on a hot and one on a cold day."""
    out = {}
    for Fc in CLASSES:
        rs = pools[Fc][:3]
        out[Fc] = [fp.fly(rs[0], 1, record="all"), fp.fly(rs[1], 2, record="all", dT=15.0),
                   fp.fly(rs[2], 3, record="all", dT=-15.0)]
    return out


def _all(whole_flights):
    return [f for fs in whole_flights.values() for f in fs]


# --- reproducibility ----------------------------------------------------------------------

def test_same_seed_same_arrays_and_different_seeds_differ(pools):
    assert fp.route_pool(2, 5, seed=7) == fp.route_pool(2, 5, seed=7)
    assert fp.route_pool(2, 5, seed=7) != fp.route_pool(2, 5, seed=8)
    route = pools[2][0]
    a, b = fp.fly(route, 42), fp.fly(route, np.random.default_rng(42))
    np.testing.assert_array_equal(a.w, b.w)
    np.testing.assert_array_equal(a.t, b.t)
    assert (a.dT, a.tra_takeoff, a.severity) == (b.dT, b.tra_takeoff, b.severity)
    c = fp.fly(route, 43)
    assert c.dT != a.dT
    n = min(len(a.w), len(c.w))
    assert not np.array_equal(a.w[:n], c.w[:n])
    u1, u2 = fp.fly_unit(pools[1], 3, seed=5), fp.fly_unit(pools[1], 2, seed=5)
    for f1, f2 in zip(u1[:2], u2, strict=True):  # flight k does not depend on n_flights
        np.testing.assert_array_equal(f1.w, f2.w)


# --- flight classes and routes ------------------------------------------------------------

def test_durations_in_class_ranges(pools, whole_flights):
    for Fc, pool in pools.items():
        lo, hi = fp.DURATION_H[Fc]
        d = np.array([r.duration_h for r in pool])
        assert np.all((d >= lo) & (d <= hi)) and all(r.Fc == Fc for r in pool)
    for f in _all(whole_flights):  # the 1 Hz trace spans the whole flight time
        assert len(f.t) == round(f.duration_h * 3600) and f.t[0] == 0.0


def test_cruise_altitude_rises_with_class(pools):
    mean_alt = [np.mean([r.cruise_alt_ft for r in pools[Fc]]) for Fc in CLASSES]
    assert mean_alt[0] < mean_alt[1] < mean_alt[2]
    for Fc in CLASSES:
        lo, hi = fp.CRUISE_ALT_FT[Fc]
        assert all(lo <= r.cruise_alt_ft <= hi and r.top_alt_ft <= 41000 for r in pools[Fc])
    assert all(r.n_steps == 0 for r in pools[1])
    assert any(r.n_steps > 0 for r in pools[3])


def test_draw_route_mixes_the_pool(pools):
    rng = np.random.default_rng(0)
    drawn = {fp.draw_route(pools[2], rng) for _ in range(200)}
    assert len(drawn) > 20 and drawn <= set(pools[2])


def test_restricted_routes_respect_caps():
    pool = fp.route_pool(1, 20, seed=3, max_cruise_alt_ft=22000.0, max_duration_h=1.5)
    assert all(r.top_alt_ft <= 22000.0 and 1.0 <= r.duration_h <= 1.5 for r in pool)
    pool2 = fp.route_pool(2, 20, seed=3, max_cruise_alt_ft=26000.0)
    assert all(r.top_alt_ft <= 26000.0 for r in pool2)
    normal = fp.route_pool(1, 20, seed=3)
    assert np.mean([r.cruise_alt_ft for r in pool]) < np.mean([r.cruise_alt_ft for r in normal])
    f = fp.fly(pool[0], 0, record="all")
    assert f.alt.max() <= 22000.0 + 100.0  # altitude-hold noise is bounded to +-100 ft
    with pytest.raises(ValueError, match="shortest Fc1"):
        fp.route_pool(1, 3, seed=0, max_duration_h=0.9)
    with pytest.raises(ValueError, match="below"):
        fp.route_pool(1, 3, seed=0, max_cruise_alt_ft=9000.0)
    with pytest.raises(ValueError, match="VMO"):  # M 0.84 at FL150 would be ~440 kt CAS
        fp.Route(Fc=1, duration_h=2.0, cruise_alt_ft=15000.0, cruise_mach=0.84)


# --- the traces ---------------------------------------------------------------------------

def test_every_point_inside_the_model_envelope(whole_flights):
    for f in _all(whole_flights):
        check_w(f.w, source=f"Fc{f.Fc} flight")
        assert f.TRA.min() >= 15.0 and f.TRA.max() <= 100.0
    bad = whole_flights[1][0].w.copy()
    bad[5, 1] = 0.95
    with pytest.raises(InputError, match=r"row 5, column Mach = 0.95 is outside the flight"):
        check_w(bad)


def test_mach_and_calibrated_airspeed_limits(whole_flights):
    for f in _all(whole_flights):
        assert f.Mach.max() <= 0.85
        cas = fp.cas_from_mach(f.Mach, f.alt)
        assert cas.max() <= 350.0
        below = (f.alt < 9800.0) & (f.phase >= 1) & (f.phase <= 3)
        assert cas[below].max() <= 252.0  # 250 kt below 10,000 ft
    # the CAS <-> Mach pair is consistent with atmosphere.mach_from_cas
    m = fp.mach_from_cas_kt(np.array([250.0, 300.0]), np.array([5000.0, 30000.0]))
    np.testing.assert_allclose(fp.cas_from_mach(m, [5000.0, 30000.0]), [250.0, 300.0],
                               rtol=1e-9)


def test_t2_is_the_atmosphere_model_for_the_flight_day(whole_flights):
    rng = np.random.default_rng(0)
    for f in _all(whole_flights):
        for i in rng.integers(0, len(f.t), 8):
            ref = float(t2_from_flight(f.alt[i], f.Mach[i], f.dT)) * 1.8
            assert f.T2[i] == pytest.approx(ref, rel=1e-12)
    hot, cold = whole_flights[2][1], whole_flights[2][2]
    assert hot.dT == 15.0 and cold.dT == -15.0
    assert hot.T2[0] - cold.T2[0] == pytest.approx(30.0 * 1.8, rel=0.01)  # on the ground


def test_phases_look_like_an_airline_flight(whole_flights):
    for f in _all(whole_flights):
        ph, t = f.phase, f.t
        assert list(np.unique(ph)) == [0, 1, 2, 3, 4]
        assert np.all(np.diff(ph) >= 0)  # roll, climb, cruise, descent, landing, in order
        roc = np.gradient(f.alt) * 60.0  # ft/min at 1 Hz
        assert roc[f.alt > 10000.0].max() < 4000.0 and roc.max() < 4000.0
        assert roc.min() > -4000.0
        climb_min = np.sum(ph == 1) / 60.0  # mean rate of climb 1,000-4,000 ft/min
        assert f.cruise_alt_ft / 4000.0 < climb_min < f.cruise_alt_ft / 1000.0
        # rate of climb falls with altitude: 250 kt segment vs the last 5,000 ft of climb
        climb = ph == 1
        low = climb & (f.alt > 4000.0) & (f.alt < 9000.0)
        high = climb & (f.alt > f.cruise_alt_ft - 5000.0) & (f.alt < f.cruise_alt_ft - 1000.0)
        if f.cruise_alt_ft >= 25000.0:
            assert roc[high].mean() < 0.8 * roc[low].mean()
        # throttle by phase
        assert 80.0 <= f.tra_takeoff <= 100.0
        assert f.TRA[(t > 15) & (ph == 0)].max() == pytest.approx(f.tra_takeoff, abs=0.01)
        cl = np.median(f.TRA[climb & (f.alt > 3000.0)])
        assert cl <= f.tra_takeoff + 0.5 and cl > f.tra_takeoff - 10.0
        cruise = ph == 2
        assert 58.0 <= np.median(f.TRA[cruise]) <= 80.0
        assert 20.0 <= np.median(f.TRA[ph == 3]) <= 35.0
        # cruise at the route's Mach and level, holding altitude within +-100 ft
        assert np.median(f.Mach[cruise]) == pytest.approx(f.cruise_mach, abs=0.005)
        level = cruise & (np.abs(roc) < 50.0)
        dev = np.abs(f.alt[level][:, None] - (f.cruise_alt_ft + 2000.0
                                              * np.arange(f.route.n_steps + 1))).min(axis=1)
        assert dev.max() <= 100.0 + 1e-9
        # smooth: no jumps in altitude, Mach; thrust ramps over a few seconds
        assert np.abs(np.diff(f.alt)).max() < 60.0
        assert np.abs(np.diff(f.Mach)).max() < 0.01
        assert np.abs(np.diff(f.TRA)).max() < 10.0
        # starts and ends on the runway
        assert f.alt[0] == 0.0 and f.Mach[0] == 0.0 and f.alt[-1] == 0.0
        assert f.Mach[-1] < 0.05


def test_step_climbs_on_long_flights(pools):
    route = next(r for r in pools[3] if r.n_steps == 2)
    f = fp.fly(route, 0)
    assert f.alt.max() == pytest.approx(route.cruise_alt_ft + 4000.0, abs=100.0)
    assert f.route.top_alt_ft == route.cruise_alt_ft + 4000.0


# --- recording and sample rate ------------------------------------------------------------

def test_default_records_only_above_10000_ft(pools, whole_flights):
    route = pools[2][0]
    rec = fp.fly(route, 1)
    full = whole_flights[2][0]
    assert rec.record == "above_10kft" and rec.t[0] == 0.0
    assert rec.alt.min() >= 10000.0
    assert rec.alt[0] < 10100.0 and rec.alt[-1] < 10100.0
    assert np.all(np.diff(rec.t) == 1.0)
    # the recorded part is exactly the above-10,000 ft part of the whole flight
    above = full.alt >= 10000.0
    np.testing.assert_array_equal(rec.w, full.w[above])
    assert rec.t_start_s == full.t[above][0]


def test_tenth_hertz_is_every_tenth_sample(pools):
    route = pools[3][0]
    for record in ("above_10kft", "all"):
        a = fp.fly(route, 9, rate_hz=1.0, record=record)
        b = fp.fly(route, 9, rate_hz=0.1, record=record)
        np.testing.assert_array_equal(b.w, a.w[::10])
        np.testing.assert_array_equal(b.t, a.t[::10])
        assert np.all(np.diff(b.t) == 10.0)
    with pytest.raises(ValueError, match="rate_hz"):
        fp.fly(route, 9, rate_hz=0.3)
    with pytest.raises(ValueError, match="record"):
        fp.fly(route, 9, record="cruise")


def test_to_frame_columns_and_attributes(pools):
    f = fp.fly(pools[1][0], 4, rate_hz=0.1)
    df = f.to_frame()
    assert list(df.columns) == ["t", "alt", "Mach", "TRA", "T2"]
    np.testing.assert_array_equal(df[["alt", "Mach", "TRA", "T2"]].to_numpy(), f.w)
    for key in ("Fc", "duration_h", "cruise_alt_ft", "cruise_mach", "dT", "severity"):
        assert key in df.attrs
    assert df.attrs["Fc"] == 1 and -15.0 <= df.attrs["dT"] <= 15.0


# --- severity -----------------------------------------------------------------------------

def test_severity_typical_medium_flight_is_one_and_short_hot_full_thrust_is_harsher(pools):
    assert fp.flight_severity(92.0, 0.0, 4.0) == pytest.approx(1.0)
    rng = np.random.default_rng(1)
    sev = [fp.fly(fp.draw_route(pools[2], rng), rng, rate_hz=0.1).severity for _ in range(25)]
    assert 0.85 < np.median(sev) < 1.2
    short = fp.Route(Fc=1, duration_h=1.2, cruise_alt_ft=22000.0, cruise_mach=0.72)
    harsh = fp.fly(short, 0, dT=15.0, tra_takeoff=100.0)
    assert harsh.severity > 2.0 and harsh.severity > 1.8 * np.median(sev)
    # monotone in each cause
    assert fp.flight_severity(100, 0, 4) > fp.flight_severity(85, 0, 4)
    assert fp.flight_severity(92, 10, 4) > fp.flight_severity(92, -10, 4)
    assert fp.flight_severity(92, 0, 1.5) > fp.flight_severity(92, 0, 7.0)


def test_an_eight_hour_flight_has_every_second():
    """Every second of a long flight is recorded, once and in order (its speed is measured
    in benchmarks/fleet_generation.py, not here)."""
    route = fp.Route(Fc=3, duration_h=8.0, cruise_alt_ft=37000.0, cruise_mach=0.84, n_steps=2)
    f = fp.fly(route, 0, record="all")
    assert len(f.t) == 8 * 3600
    np.testing.assert_array_equal(np.diff(f.t), 1.0)
