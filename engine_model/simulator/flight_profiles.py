"""Flight profiles: the scenario descriptors ``w = (alt, Mach, TRA, T2)`` of one airline flight.

A flight is generated at 1 Hz from brake release to the end of the landing roll, then cut to the
recorded part and decimated (never regenerated). Every random choice comes from the seed or
``numpy.random.Generator`` the caller passes: same seed, identical arrays.

Flight classes (as N-CMAPSS, Arias Chao et al., *Data* 6(1):5, 2021: class 1 flights
last 1-3 h, class 2 3-5 h, class 3 more than 5 h; we cap class 3 at 8 h)::

    Fc  duration [h]  initial cruise level  cruise Mach (before the CAS cap)  step climbs
    1   1 - 3         FL200 - FL300         0.76 - 0.80                        none
    2   3 - 5         FL300 - FL370         0.77 - 0.82                        one 2,000 ft step on
                                                                               half the routes > 4 h
    3   5 - 8         FL340 - FL380         0.80 - 0.84                        up to two 2,000 ft
                                                                               steps, never above
                                                                               FL410

The cruise levels are our choice (engineering judgement, not from a data source): they only have
to rise with the class, as the paper's test units 14 and 15 show (shorter flights are also the
lower ones). Cruise Mach is further capped at 320 kt calibrated airspeed, because below the
crossover altitude a jet cruises CAS-limited (M 0.80 at FL200 is 370 kt CAS, above a typical
VMO of 340-350 kt); so a low Fc1 route cruises at M 0.70-0.76 and ``Route.cruise_mach`` is the
Mach actually flown.

Phases (CAS schedules as in airline flight manuals; 250 kt below 10,000 ft is the regulatory
limit of FAA 14 CFR 91.117(a) and of ICAO Annex 11 in most airspace classes):

- take-off roll: TRA spools up from ground idle to the take-off TRA in 10 s; the take-off TRA is
  ``100 (1 - d)``, ``d ~ U(0, d_max)`` a reduced-thrust (assumed-temperature) derate with
  ``d_max = (0.20 - 0.006 max(dT, 0)) k_Fc``, ``k_Fc = 1, 0.85, 0.6``: less flex on hot days and
  for the heavier long-haul take-offs. So TRA_TO is 80-100 %. Acceleration 1.3-2.3 m/s^2 to a
  lift-off speed of 140-170 kt (by class).
- climb: V2 + 10 kt to 1,500 ft (thrust reduction to climb TRA = TRA_TO - U(3, 8), never below
  cruise TRA + 4), accelerate to 250 kt by 3,000 ft, 250 kt to 10,000 ft, accelerate to the
  climb CAS (285-315 kt) by 11,500 ft, then that CAS to the crossover with the cruise Mach.
  Rate of climb ``roc0 max(0.35, 1 - h / 55,000 ft)`` with ``roc0`` 2,700-3,300 ft/min (Fc1),
  2,400-3,000 (Fc2), 2,100-2,700 (Fc3, heavier), times ``1 - 0.006 dT`` (hot days climb
  slower), reduced in the acceleration segments, with an exponential altitude capture (time
  constant 20 s): about 2,500 ft/min at 10,000 ft falling to 800-1,000 ft/min near FL370, 15-20
  min to FL300 and 25-35 min to FL370.
- cruise: constant Mach; TRA starts at 62-74 % (Fc1), 64-76 (Fc2), 68-78 (Fc3) and falls by
  0.8 %/h as fuel burns; a slow random walk (Ornstein-Uhlenbeck, sigma 1 %, tau 600 s) plus
  turbulence (sigma 0.3 %, tau 5 s) on TRA; altitude-hold noise (second-order, sigma 35 ft,
  bounded to +-100 ft) and Mach-hold noise (sigma 0.0015, bounded to +-0.004). Step climbs of
  2,000 ft at up to 1,000 ft/min with climb TRA.
- descent: idle (TRA_idle 20-30 %) at the cruise Mach to the crossover with the descent CAS
  (270-310 kt), slow to 250 kt between 11,500 and 10,000 ft, 250 kt to 4,000 ft, slow to the
  approach speed (130-155 kt) by 1,800 ft with approach thrust (TRA 40-55 %), a 3 degree glide
  path (ROD = 5.3 V_app ft/min), a flare below 50 ft, touchdown, and a landing roll at ground
  idle (1.8 m/s^2) down to 20 kt. Rate of descent ``rod0 (0.55 + 0.45 h / 40,000 ft)``,
  ``rod0`` 2,600-3,200 ft/min, as the "3 nm per 1,000 ft" rule of thumb gives.

Day temperature: ``dT ~ U(-15 K, +15 K)`` per flight (uniform, as
:func:`engine_model.analysis.sampling.random_envelope`; it covers hot and cold days evenly, which a
training set needs more than a realistic seasonal histogram). T2 is
:func:`engine_model.physics.atmosphere.t2_from_flight` ``(alt, Mach, dT)`` in degR; the airport is
at sea level.

Recording: by default, as in N-CMAPSS, only the part of the flight at or above 10,000 ft is
kept (``record="above_10kft"``); ``record="all"`` keeps brake release to the end of the landing
roll. ``rate_hz=0.1`` (the paper) keeps every 10th sample of the 1 Hz trace.

Severity (wear per flight hour, for the degradation model), normalised to 1 for the reference
medium flight (4 h, TRA_TO 92 %, ISA)::

    damage   = C_CYCLE f_TO + duration_h f_hr           [reference flight-hour equivalents]
    f_TO     = exp(0.5 (TRA_TO - 92) / 10 + 0.3 dT / 10)   take-off / climb cycle
    f_hr     = exp(0.1 dT / 10)                             time at temperature
    severity = (damage / duration_h) / ((C_CYCLE + 4) / 4),   C_CYCLE = 1.4

``C_CYCLE = 1.4``: one take-off cycle costs as much life as 1.4 reference cruise hours, so the
interval between shop visits, counted in flight hours, grows by ~40 % from 1 to 2 h per cycle and
~65 % from 1 to 3 h: the shape (not calibrated numbers) of the published interval-versus-
flight-length curves of airline engines (e.g. S. Ackert, "Engine maintenance concepts for
financiers", 2011). The thrust and temperature factors are round engineering numbers (each 10 %
of take-off derate saves ~40 % of the cycle damage; +10 K of day temperature costs ~35 % on the
cycle, ~10 % on the hours), not fitted to data. The damage of a flight in reference
flight hours is ``severity * duration_h``. A short, hot, full-thrust flight scores 2-3.
"""

from dataclasses import dataclass, field
from functools import lru_cache

import casadi as ca
import numpy as np
from scipy.signal import lfilter

from engine_model.channels import W_NAMES
from engine_model.physics import atmosphere
from engine_model.units import FT_TO_M, KT_TO_MS, R_PER_K

# --- flight classes ------------------------------------------------------------------------
DURATION_H = {1: (1.0, 3.0), 2: (3.0, 5.0), 3: (5.0, 8.0)}
CRUISE_ALT_FT = {1: (20000.0, 30000.0), 2: (30000.0, 37000.0), 3: (34000.0, 38000.0)}
CRUISE_MACH = {1: (0.76, 0.80), 2: (0.77, 0.82), 3: (0.80, 0.84)}
STEP_FT = 2000.0
MAX_ALT_FT = 41000.0  # certified ceiling of the airliners this engine class powers
MIN_CRUISE_ALT_FT = 12000.0  # a flight must have a part above 10,000 ft to record
CRUISE_CAS_MAX_KT = 320.0  # cruise below the crossover altitude is flown at this CAS
VMO_KT = 340.0  # maximum operating speed of the airliners this engine class powers
RECORD_ALT_FT = 10000.0
DT_RANGE_K = (-15.0, 15.0)

# --- per-class performance draws (uniform ranges) -------------------------------------------
_ROC0 = {1: (2700.0, 3300.0), 2: (2400.0, 3000.0), 3: (2100.0, 2700.0)}  # ft/min at sea level
_ROD0 = (2600.0, 3200.0)  # ft/min, scaled with altitude
_V_LOF = {1: (140.0, 155.0), 2: (145.0, 160.0), 3: (155.0, 170.0)}  # kt
_V_APP = {1: (130.0, 145.0), 2: (135.0, 150.0), 3: (140.0, 155.0)}  # kt
_TRA_CR0 = {1: (62.0, 74.0), 2: (64.0, 76.0), 3: (68.0, 78.0)}  # % at top of climb
_DERATE_K = {1: 1.0, 2: 0.85, 3: 0.6}
_CAS_CLB = (285.0, 315.0)  # kt
_CAS_DES = (270.0, 310.0)  # kt
_TRA_IDLE = (20.0, 30.0)
_TRA_APP = (40.0, 55.0)
TRA_CRUISE_TREND = 0.8  # % per hour, fuel burn
_TRA_RANGE = (15.0, 100.0)

# --- severity ------------------------------------------------------------------------------
C_CYCLE = 1.4
SEVERITY_REF = {"duration_h": 4.0, "tra_takeoff": 92.0, "dT": 0.0}

PHASES = ("roll", "climb", "cruise", "descent", "landing")


# === atmosphere helpers (vectorised) ======================================================

@lru_cache(maxsize=1)
def _casadi_fns():
    cas, alt = ca.SX.sym("cas"), ca.SX.sym("alt")
    f_mach = ca.Function("mach_from_cas", [cas, alt], [atmosphere.mach_from_cas(cas, alt)])
    f_p = ca.Function("isa_pressure", [alt], [atmosphere.isa_pressure(alt)])
    return f_mach, f_p


def mach_from_cas_kt(cas_kt, alt_ft):
    """Mach [-] of a calibrated airspeed [kt] at pressure altitude [ft] (arrays broadcast)."""
    cas_kt, alt_ft = np.broadcast_arrays(np.asarray(cas_kt, float), np.asarray(alt_ft, float))
    f_mach, _ = _casadi_fns()
    out = f_mach(cas_kt.reshape(1, -1) * KT_TO_MS, alt_ft.reshape(1, -1))
    return np.asarray(out).reshape(cas_kt.shape)


def cas_from_mach(mach, alt_ft):
    """Calibrated airspeed [kt] at Mach and pressure altitude [ft]: the inverse of
    :func:`engine_model.physics.atmosphere.mach_from_cas` (subsonic, ISA pressure)."""
    mach, alt_ft = np.broadcast_arrays(np.asarray(mach, float), np.asarray(alt_ft, float))
    _, f_p = _casadi_fns()
    p = np.asarray(f_p(alt_ft.reshape(1, -1))).reshape(alt_ft.shape)
    qc = p * ((1.0 + 0.2 * mach**2) ** 3.5 - 1.0)
    a0 = (1.4 * atmosphere.R_ISA * atmosphere.T_STD_K) ** 0.5
    cas = a0 * np.sqrt(5.0 * ((qc / atmosphere.P_STD_PA + 1.0) ** (2.0 / 7.0) - 1.0))
    return cas / KT_TO_MS


def t2_degR(alt_ft, mach, dT):
    """Fan-inlet total temperature [degR]: :func:`atmosphere.t2_from_flight` in numpy.

    Same equations (ISA static temperature + ``dT``, real-gas stagnation of
    :func:`atmosphere.total_temperature`), evaluated on arrays without building CasADi graphs.
    """
    ts = np.maximum(atmosphere.T_STD_K - atmosphere.LAPSE * np.asarray(alt_ft) * FT_TO_M,
                    atmosphere.T_TROPOPAUSE) + dT
    return np.asarray(atmosphere.total_temperature(ts, np.asarray(mach))) * R_PER_K


# === routes ===============================================================================

@dataclass(frozen=True)
class Route:
    """An airline route: flight class, flight time, initial cruise level, cruise Mach.

    ``duration_h`` is brake release to the end of the landing roll. ``n_steps`` step climbs of
    2,000 ft are flown at evenly spaced times in the cruise.
    """

    Fc: int
    duration_h: float
    cruise_alt_ft: float
    cruise_mach: float
    n_steps: int = 0

    def __post_init__(self):
        if self.Fc not in DURATION_H:
            raise ValueError(f"Route: flight class Fc={self.Fc} must be 1, 2 or 3")
        if not 0.5 <= self.duration_h <= 10.0:
            raise ValueError(f"Route: duration_h={self.duration_h} outside 0.5-10 h")
        if int(self.n_steps) != self.n_steps or self.n_steps < 0:
            raise ValueError(f"Route: n_steps={self.n_steps} must be a whole number >= 0")
        top = self.cruise_alt_ft + self.n_steps * STEP_FT
        if not (MIN_CRUISE_ALT_FT <= self.cruise_alt_ft and top <= MAX_ALT_FT):
            raise ValueError(f"Route: cruise altitude {self.cruise_alt_ft:g} ft with"
                             f" {self.n_steps} step(s) must stay within"
                             f" {MIN_CRUISE_ALT_FT:g}-{MAX_ALT_FT:g} ft")
        if not 0.5 <= self.cruise_mach <= 0.84:
            raise ValueError(f"Route: cruise_mach={self.cruise_mach} outside 0.5-0.84")
        cas = float(cas_from_mach(self.cruise_mach, self.cruise_alt_ft))
        if cas > VMO_KT:
            raise ValueError(f"Route: Mach {self.cruise_mach} at {self.cruise_alt_ft:g} ft is"
                             f" {cas:.0f} kt CAS, above VMO {VMO_KT:g} kt; fly a lower Mach"
                             " or a higher level")

    @property
    def top_alt_ft(self):
        """Highest cruise level, after the step climbs."""
        return self.cruise_alt_ft + self.n_steps * STEP_FT


def _as_rng(seed):
    return seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)


def route_pool(Fc, n_routes, seed=0, max_cruise_alt_ft=None, max_duration_h=None):
    """``n_routes`` routes of flight class ``Fc`` (1, 2, 3) an airline could fly one unit on.

    ``max_cruise_alt_ft`` / ``max_duration_h`` restrict the unit to lower / shorter flights
    (the paper's test units 14 and 15): durations are drawn in ``[lo, min(hi, max_duration_h)]``
    of the class; cruise levels in ``[min(lo, cap - 4,000 ft), min(hi, cap)]`` (never below
    12,000 ft) and step climbs stop at the cap. A route too short for a climb to its level and a
    descent from it (with the slowest climb and descent of its class, plus 10 min of cruise) is
    moved down 1,000 ft at a time.
    """
    if Fc not in DURATION_H:
        raise ValueError(f"route_pool: flight class Fc={Fc} must be 1, 2 or 3")
    if int(n_routes) < 1:
        raise ValueError(f"route_pool: n_routes={n_routes} must be >= 1")
    rng = _as_rng(seed)
    d_lo, d_hi = DURATION_H[Fc]
    if max_duration_h is not None:
        if max_duration_h <= d_lo:
            raise ValueError(f"route_pool: max_duration_h={max_duration_h} is not above the"
                             f" shortest Fc{Fc} flight ({d_lo:g} h)")
        d_hi = min(d_hi, float(max_duration_h))
    a_lo, a_hi = CRUISE_ALT_FT[Fc]
    ceiling = MAX_ALT_FT
    if max_cruise_alt_ft is not None:
        if max_cruise_alt_ft < MIN_CRUISE_ALT_FT:
            raise ValueError(f"route_pool: max_cruise_alt_ft={max_cruise_alt_ft} is below"
                             f" {MIN_CRUISE_ALT_FT:g} ft; a flight must be recorded above"
                             f" {RECORD_ALT_FT:g} ft")
        ceiling = min(ceiling, float(max_cruise_alt_ft))
        a_hi = min(a_hi, ceiling)
        a_lo = max(MIN_CRUISE_ALT_FT, min(a_lo, a_hi - 4000.0))
    levels = np.arange(np.ceil(a_lo / 1000.0), np.floor(a_hi / 1000.0) + 1.0) * 1000.0
    m_lo, m_hi = CRUISE_MACH[Fc]
    routes = []
    for _ in range(int(n_routes)):
        dur = float(np.round(rng.uniform(d_lo, d_hi), 3))
        dur = min(max(dur, d_lo), d_hi)
        alt = float(rng.choice(levels))
        mach_draw = float(np.round(rng.uniform(m_lo, m_hi), 2))
        step_draw = rng.uniform()
        room = int((ceiling - alt) // STEP_FT)
        if Fc == 3:
            n_steps = min(2, room)
        elif Fc == 2 and dur > 4.0 and step_draw < 0.5:
            n_steps = min(1, room)
        else:
            n_steps = 0
        while alt > MIN_CRUISE_ALT_FT and _min_duration_s(Fc, alt, n_steps) > dur * 3600.0:
            alt = max(MIN_CRUISE_ALT_FT, alt - 1000.0)
        if _min_duration_s(Fc, alt, n_steps) > dur * 3600.0:
            raise ValueError(f"route_pool: a {dur:g} h flight is too short to climb to"
                             f" {MIN_CRUISE_ALT_FT:g} ft and descend")
        m_cap = float(mach_from_cas_kt(CRUISE_CAS_MAX_KT, alt))
        mach = min(mach_draw, np.floor(m_cap * 1000.0) / 1000.0)
        routes.append(Route(Fc, dur, alt, float(mach), n_steps))
    return routes


def draw_route(pool, rng):
    """One route of ``pool`` for the next flight (uniform choice)."""
    return pool[int(_as_rng(rng).integers(len(pool)))]


# === per-flight parameters ================================================================

@dataclass(frozen=True)
class _Params:
    dT: float
    tra_to: float
    tra_cl: float
    tra_cr0: float
    tra_idle: float
    tra_app: float
    roc0: float  # ft/min, already with the hot-day factor
    rod0: float  # ft/min
    v_lof: float  # kt
    v_app: float  # kt
    cas_clb: float  # kt
    cas_des: float  # kt
    a_roll: float  # m/s^2


def _draw_params(Fc, rng, dT=None, tra_takeoff=None):
    u = rng.uniform(size=12)  # one block of draws: the order never depends on overrides

    def lerp(rng_pair, x):
        return rng_pair[0] + (rng_pair[1] - rng_pair[0]) * x

    dT = float(lerp(DT_RANGE_K, u[0])) if dT is None else float(dT)
    d_max = (0.20 - 0.006 * max(dT, 0.0)) * _DERATE_K[Fc]
    tra_to = 100.0 * (1.0 - u[1] * d_max) if tra_takeoff is None else float(tra_takeoff)
    tra_cr0 = lerp(_TRA_CR0[Fc], u[2])
    tra_cl = min(tra_to, max(tra_to - lerp((3.0, 8.0), u[3]), tra_cr0 + 4.0))
    tra_idle = lerp(_TRA_IDLE, u[4])
    roc0 = lerp(_ROC0[Fc], u[5]) * (1.0 - 0.006 * dT)
    a_roll = 1.5 + 0.8 * (tra_to - 80.0) / 20.0 - (0.2 if Fc == 3 else 0.0)
    return _Params(
        dT=dT, tra_to=float(tra_to), tra_cl=float(tra_cl), tra_cr0=float(tra_cr0),
        tra_idle=float(tra_idle), tra_app=float(lerp(_TRA_APP, u[6])), roc0=float(roc0),
        rod0=float(lerp(_ROD0, u[7])), v_lof=float(lerp(_V_LOF[Fc], u[8])),
        v_app=float(lerp(_V_APP[Fc], u[9])), cas_clb=float(lerp(_CAS_CLB, u[10])),
        cas_des=float(lerp(_CAS_DES, u[11])), a_roll=float(max(a_roll, 1.2)))


def _worst_params(Fc):
    """Slowest climb and descent of a class (hot day, heavy): for route feasibility."""
    return _Params(dT=15.0, tra_to=80.0, tra_cl=75.0, tra_cr0=70.0, tra_idle=25.0,
                   tra_app=45.0, roc0=_ROC0[Fc][0] * 0.91, rod0=_ROD0[0], v_lof=_V_LOF[Fc][1],
                   v_app=_V_APP[Fc][0], cas_clb=285.0, cas_des=270.0, a_roll=1.2)


# === climb and descent on an altitude grid ================================================

_DH = 10.0  # ft, integration grid
_DECEL_LAND = 1.8  # m/s^2, landing roll (brakes, no reverse thrust)
_DH_MACH = 100.0  # ft, grid on which Mach is evaluated (then interpolated)


def _time_of_alt(h, rate_ftmin):
    """Cumulative time [s] along the altitude grid ``h`` flown at ``rate_ftmin`` [ft/min]."""
    inv = 60.0 / rate_ftmin
    return np.concatenate([[0.0], np.cumsum(0.5 * (inv[1:] + inv[:-1]) * np.diff(h))])


def _climb_rate(h, h_top, p):
    sched = p.roc0 * np.maximum(0.35, 1.0 - h / 55000.0)
    mult = np.interp(h, [0, 50, 1400, 1600, 2900, 3100, 9900, 10100, 11400, 11600],
                     [0.3, 1, 1, 0.6, 0.6, 1, 1, 0.5, 0.5, 1])
    capture = np.maximum(100.0, 3.0 * (h_top - h))  # 20 s time constant
    return np.minimum(sched * mult, capture)


def _climb_cas(h, p):
    return np.interp(h, [0, 400, 1500, 3000, 10000, 11500],
                     [p.v_lof, p.v_lof + 15, p.v_lof + 15, 250, 250, p.cas_clb])


def _descent_rate(h, h_top, p):
    sched = p.rod0 * (0.55 + 0.45 * h / 40000.0)
    sched = sched * np.interp(h, [1800, 1900, 3900, 4100, 9900, 10100, 11400, 11600],
                              [0.5, 0.5, 0.5, 1, 1, 0.4, 0.4, 1])
    rod_gs = 5.3 * p.v_app  # 3 degree glide path, ft/min
    sched = np.where(h < 1800.0, rod_gs, sched)
    sched = np.where(h < 50.0, 150.0 + (rod_gs - 150.0) * h / 50.0, sched)  # flare
    pitch_over = np.maximum(100.0, 3.0 * (h_top - h))
    return np.minimum(sched, pitch_over)


def _descent_cas(h, h_top, cas_top, p):
    cas = np.interp(h, [0, 1800, 4000, 10000, 11500], [p.v_app, p.v_app, 250, 250, p.cas_des])
    blend = np.clip((h - (h_top - 2000.0)) / 2000.0, 0.0, 1.0)
    return cas + max(0.0, cas_top - p.cas_des) * blend


def _climb(h_top, p):
    h = np.arange(0.0, h_top + 0.5 * _DH, _DH)
    h[-1] = h_top
    return h, _time_of_alt(h, _climb_rate(h, h_top, p))


def _descent(h_top, p):
    """Altitude grid from ``h_top`` down to 0 and the time [s] from top of descent."""
    h = np.arange(0.0, h_top + 0.5 * _DH, _DH)
    h[-1] = h_top
    t_up = _time_of_alt(h, _descent_rate(h, h_top, p))
    return h[::-1], (t_up[-1] - t_up)[::-1]


def _ground_times(p):
    t_roll = p.v_lof * KT_TO_MS / p.a_roll
    t_land = (p.v_app - 20.0) * KT_TO_MS / _DECEL_LAND
    return t_roll, t_land


def _step_time_s():
    return 1.5 * STEP_FT / 1000.0 * 60.0  # smoothstep, peak 1,000 ft/min


def _min_cruise_s(n_steps):
    """Shortest cruise :func:`fly` accepts: level-off, Mach capture, room for the steps."""
    return 120.0 + n_steps * (_step_time_s() + 300.0)


def _min_duration_s(Fc, alt, n_steps):
    """Shortest route to ``alt`` with the slowest climb and descent of the class, plus 10 min
    of margin over :func:`_min_cruise_s`."""
    p = _worst_params(Fc)
    top = alt + n_steps * STEP_FT
    t_roll, t_land = _ground_times(p)
    return (t_roll + _climb(alt, p)[1][-1] + _descent(top, p)[1][-1] + t_land
            + _min_cruise_s(n_steps) + 600.0)


def _mach_schedule(h, cas_kt, mach_max):
    """min(mach_max, Mach(CAS(h), h)) evaluated on a 100-ft grid, interpolated onto ``h``."""
    lo, hi = float(np.min(h)), float(np.max(h))
    hc = np.linspace(lo, hi, max(2, int(np.ceil((hi - lo) / _DH_MACH)) + 1))
    cas_c = np.interp(hc, h, cas_kt) if h[0] <= h[-1] else np.interp(hc, h[::-1], cas_kt[::-1])
    m_c = np.minimum(mach_max, mach_from_cas_kt(cas_c, hc))
    return np.interp(h, hc, m_c)


# === noise ================================================================================

def _ou(rng, n, sigma, tau_s):
    """First-order Ornstein-Uhlenbeck at 1 Hz, stationary from the first sample."""
    phi = np.exp(-1.0 / tau_s)
    e = rng.standard_normal(n + 1)
    zi = np.array([phi * e[0]])
    return sigma * lfilter([np.sqrt(1.0 - phi**2)], [1.0, -phi], e[1:], zi=zi)[0]


def _ou2(rng, n, sigma, tau_s):
    """Second-order (two cascaded OU) noise at 1 Hz: smooth, stationary std ``sigma``."""
    phi = np.exp(-1.0 / tau_s)
    burn = int(10 * tau_s)
    e = rng.standard_normal(n + burn)
    y = lfilter([1.0], [1.0, -2.0 * phi, phi**2], e)[burn:]
    return sigma * y / np.sqrt((1.0 + phi**2) / (1.0 - phi**2) ** 3)


def _bounded(x, bound):
    return bound * np.tanh(x / bound)


# === severity =============================================================================

def flight_severity(tra_takeoff, dT, duration_h):
    """Wear per flight hour relative to the reference medium flight (4 h, TRA_TO 92 %, ISA).

    See the module docstring for the formula and its basis. ``severity * duration_h`` is the
    damage of the flight in reference flight hours.
    """
    f_to = np.exp(0.5 * (tra_takeoff - SEVERITY_REF["tra_takeoff"]) / 10.0 + 0.3 * dT / 10.0)
    f_hr = np.exp(0.1 * dT / 10.0)
    d_ref = SEVERITY_REF["duration_h"]
    per_hour = (C_CYCLE * f_to + duration_h * f_hr) / duration_h
    return float(per_hour / ((C_CYCLE + d_ref) / d_ref))


# === the flight ===========================================================================

@dataclass
class FlightRecord:
    """One recorded flight: ``w`` is (n, 4) in W_NAMES order (alt ft, Mach, TRA %, T2 degR).

    ``t`` [s] counts from the first recorded sample (``record="above_10kft"``) or from brake
    release (``record="all"``); ``t_start_s`` is the brake-release time of ``t = 0``.
    ``phase`` indexes :data:`PHASES`. ``duration_h`` is the whole flight, recorded or not.
    """

    t: np.ndarray
    w: np.ndarray
    phase: np.ndarray
    route: Route
    dT: float
    tra_takeoff: float
    severity: float
    rate_hz: float
    record: str
    t_start_s: float
    attrs: dict = field(default_factory=dict)

    @property
    def Fc(self):
        return self.route.Fc

    @property
    def duration_h(self):
        return self.route.duration_h

    @property
    def cruise_alt_ft(self):
        return self.route.cruise_alt_ft

    @property
    def top_alt_ft(self):
        return self.route.top_alt_ft

    @property
    def cruise_mach(self):
        return self.route.cruise_mach

    @property
    def alt(self):
        return self.w[:, 0]

    @property
    def Mach(self):
        return self.w[:, 1]

    @property
    def TRA(self):
        return self.w[:, 2]

    @property
    def T2(self):
        return self.w[:, 3]

    def to_frame(self):
        """DataFrame with columns t, alt, Mach, TRA, T2; the scalars in ``df.attrs``."""
        import pandas as pd

        df = pd.DataFrame(self.w, columns=list(W_NAMES))
        df.insert(0, "t", self.t)
        df.attrs.update(
            Fc=self.Fc, duration_h=self.duration_h, cruise_alt_ft=self.cruise_alt_ft,
            top_alt_ft=self.top_alt_ft, cruise_mach=self.cruise_mach, dT=self.dT,
            tra_takeoff=self.tra_takeoff, severity=self.severity, rate_hz=self.rate_hz,
            record=self.record, t_start_s=self.t_start_s, **self.attrs)
        return df


def _decimation_step(rate_hz):
    step = int(round(1.0 / rate_hz)) if rate_hz > 0 else 0
    if step < 1 or abs(step * rate_hz - 1.0) > 1e-9:
        raise ValueError(f"fly: rate_hz={rate_hz} must be 1 Hz divided by a whole number"
                         " (1.0, 0.5, 0.1, ...)")
    return step


def fly(route, rng, rate_hz=1.0, record="above_10kft", dT=None, tra_takeoff=None):
    """Fly ``route`` once: the scenario descriptors at ``rate_hz`` of the recorded part.

    ``rng`` is a seed or a ``numpy.random.Generator``. ``dT`` [K] and ``tra_takeoff`` [%]
    override the day's ISA offset and the take-off thrust (otherwise drawn). The whole flight
    is generated at 1 Hz, cut to ``record`` ("above_10kft" or "all") and decimated by taking
    every ``1 / rate_hz``-th sample.
    """
    if record not in ("above_10kft", "all"):
        raise ValueError(f"fly: record={record!r} must be 'above_10kft' or 'all'")
    step = _decimation_step(rate_hz)
    if tra_takeoff is not None and not 80.0 <= tra_takeoff <= 100.0:
        raise ValueError(f"fly: tra_takeoff={tra_takeoff} outside 80-100 %")
    if dT is not None and not -30.0 <= dT <= 30.0:
        raise ValueError(f"fly: dT={dT} K outside ISA +-30 K")
    rng = _as_rng(rng)
    p = _draw_params(route.Fc, rng, dT, tra_takeoff)
    m_cr, h_cr, h_top = route.cruise_mach, route.cruise_alt_ft, route.top_alt_ft

    # --- timeline [s from brake release] ---
    n = int(round(route.duration_h * 3600.0))
    t_end = float(n - 1)
    t_roll, t_land = _ground_times(p)
    h_c, tc = _climb(h_cr, p)
    h_d, td = _descent(h_top, p)
    t_toc = t_roll + tc[-1]
    t_tod = t_end - t_land - td[-1]
    t_step = _step_time_s()
    cruise_s = t_tod - t_toc
    if cruise_s < _min_cruise_s(route.n_steps):
        raise ValueError(f"fly: {route} is too short: climb and descent leave"
                         f" {cruise_s:.0f} s of cruise")
    t_steps = t_toc + cruise_s * np.arange(1, route.n_steps + 1) / (route.n_steps + 1)

    # --- altitude and Mach knots ---
    v_roll = np.linspace(0.0, p.v_lof, 12)
    m_roll = mach_from_cas_kt(v_roll, 0.0)
    m_clb = _mach_schedule(h_c, _climb_cas(h_c, p), m_cr)
    cas_top = float(cas_from_mach(m_cr, h_top))
    m_des = _mach_schedule(h_d, _descent_cas(h_d, h_top, cas_top, p), m_cr)
    v_land = np.linspace(p.v_app, 20.0, 8)
    m_land = mach_from_cas_kt(v_land[1:], 0.0)
    # cruise: Mach ramp at top of climb if the climb ended CAS-limited, step climbs
    s = np.linspace(0.0, 1.0, 25)
    smooth = s * s * (3.0 - 2.0 * s)
    t_cr = [np.array([t_toc + 90.0])]
    a_cr = [np.array([h_cr])]
    for k, ts in enumerate(t_steps):
        t_cr.append(ts + s * t_step)
        a_cr.append(h_cr + STEP_FT * (k + smooth))
    t_cr = np.concatenate(t_cr + [np.array([t_tod])])
    a_cr = np.concatenate(a_cr + [np.array([h_top])])
    t_td = t_end - t_land  # touchdown
    kt = np.concatenate([v_roll * KT_TO_MS / p.a_roll, t_roll + tc[1:], t_cr, t_tod + td[1:],
                         t_td + (p.v_app - v_land[1:]) * KT_TO_MS / _DECEL_LAND])
    k_alt = np.concatenate([np.zeros(12), h_c[1:], a_cr, h_d[1:], np.zeros(7)])
    k_mach = np.concatenate([m_roll, m_clb[1:], np.full(len(t_cr), m_cr), m_des[1:], m_land])
    t = np.arange(n, dtype=float)
    alt = np.interp(t, kt, k_alt)
    mach = np.interp(t, kt, k_mach)

    # --- throttle knots ---
    t_red = t_roll + float(np.interp(1500.0, h_c, tc))
    t_lvl = t_roll + float(np.interp(h_cr - 200.0, h_c, tc))
    tra_cr_end = p.tra_cr0 - TRA_CRUISE_TREND * (t_tod - t_lvl) / 3600.0
    t_app = t_tod + float(np.interp(-1800.0, -h_d, td))
    t_flare = t_tod + float(np.interp(-50.0, -h_d, td))
    gi = max(16.0, p.tra_idle - 4.0)
    k_t = [0.0, 10.0, t_red, t_red + 8.0, t_lvl, t_lvl + 40.0, t_tod, t_tod + 10.0,
           t_app, t_app + 10.0, t_flare, t_flare + 4.0, t_td, t_td + 3.0, t_end]
    k_v = [gi, p.tra_to, p.tra_to, p.tra_cl, p.tra_cl, p.tra_cr0, tra_cr_end, p.tra_idle,
           p.tra_idle, p.tra_app, p.tra_app, p.tra_idle, p.tra_idle, gi, gi]
    tra = np.interp(t, np.maximum.accumulate(k_t), k_v)
    for ts in t_steps:  # climb thrust during step climbs
        bump = np.interp(t, [ts - 10.0, ts, ts + t_step, ts + t_step + 20.0], [0, 1, 1, 0])
        tra += bump * (p.tra_cl - np.interp(ts, t, tra))

    # --- noise (weights ramp in and out; none on the ground) ---
    w_cr = np.interp(t, [t_toc + 30.0, t_toc + 150.0, t_tod - 120.0, t_tod], [0, 1, 1, 0])
    w_tra = np.interp(t, [t_roll, t_roll + 60.0, t_toc, t_toc + 120.0, t_tod - 60.0, t_tod,
                          t_td - 60.0, t_td], [0, 0.3, 0.3, 1, 1, 0.2, 0.2, 0])
    alt += w_cr * _bounded(_ou2(rng, n, 35.0, 60.0), 100.0)
    mach += w_cr * _bounded(_ou2(rng, n, 0.0015, 60.0), 0.004)
    tra += w_tra * (_ou(rng, n, 1.0, 600.0) + _ou(rng, n, 0.3, 5.0))
    np.clip(tra, *_TRA_RANGE, out=tra)
    np.clip(mach, 0.0, None, out=mach)

    phase = np.searchsorted(np.array([t_roll, t_toc, t_tod, t_td]), t, side="right")

    # --- record and decimate, then T2 on the kept samples only ---
    if record == "above_10kft":
        above = np.flatnonzero(alt >= RECORD_ALT_FT)
        i0, i1 = int(above[0]), int(above[-1]) + 1
    else:
        i0, i1 = 0, n
    keep = slice(i0, i1, step)
    alt_k, mach_k = alt[keep], mach[keep]
    w = np.column_stack([alt_k, mach_k, tra[keep], t2_degR(alt_k, mach_k, p.dT)])
    return FlightRecord(
        t=t[keep] - t[i0], w=w, phase=phase[keep].astype(np.int8), route=route, dT=p.dT,
        tra_takeoff=p.tra_to, severity=flight_severity(p.tra_to, p.dT, route.duration_h),
        rate_hz=float(rate_hz), record=record, t_start_s=float(t[i0]))


def fly_unit(pool, n_flights, seed=0, **kwargs):
    """``n_flights`` consecutive flights of one unit, each on a route drawn from ``pool``.

    Flight ``k`` uses its own child of ``numpy.random.SeedSequence(seed)``, so it is the same
    whatever ``n_flights`` is. ``kwargs`` go to :func:`fly`.
    """
    children = np.random.SeedSequence(seed).spawn(int(n_flights))
    out = []
    for child in children:
        rng = np.random.default_rng(child)
        out.append(fly(draw_route(pool, rng), rng, **kwargs))
    return out
