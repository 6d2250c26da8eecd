"""The candidate effects of the discrepancy loop and their exact output sensitivities.

A *candidate* is one instance of a registered effect (:mod:`engine_model.physics.effects`) with
parameters ``phi`` that are absent at their neutral (default) values: a physical effect of the
steady state (customer bleed, HP off-take, Reynolds effects, inlet loss, nozzle areas), a map
adaptation of one component (``map_scaling``, one instance per component, when named), or a
sensor effect on one measured channel (bias and gain, gain drift with cycles), one instance per
channel.

Two kinds, one interface (:class:`CandidateModel`):

- *Steady* candidates are built into one model variant,
  ``EngineModel(effects=[every steady candidate])`` (compiled to C once, cached on disk). At
  ``phi = 0`` it is the base model, and with the accepted effects' values in ``p`` it is the
  current model: every solve and every exact sensitivity ``dy/dtheta``, ``dy/dp`` of the loop
  goes through this one variant
  (:meth:`engine_model.solver.model.EngineModel.sensitivities_of`: of the channels read).
- *Sensor* candidates do not change the steady state: a reading ``y_c`` becomes
  ``reading(F_c, phi)``. Their derivatives are those of the effect's own
  :meth:`~engine_model.physics.effects.Effect.apply` on the hook ``sensor:<channel>``,
  differentiated by CasADi (exact), so a user's own sensor effect is tested the same way.

Parameters that are unidentified at the null (a *nuisance present only under the
alternative*, Davies 1977), e.g. the Reynolds effect's ``flow_ratio`` (meaningless while the
exponent ``n`` is 0), are held at their documented default and listed in
:attr:`Candidate.fixed`. A parameter whose documented range starts (ends) at its neutral value
is one-sided (``phi >= 0``): its test has a boundary null (:mod:`.score_statistics`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from engine_model.channels import OUTPUT_NAMES, THETA_NAMES
from engine_model.physics.effect_library import COMPONENT_MODS, SensorEffect
from engine_model.physics.effects import Effect, EffectSet, parse_effect_spec, registry
from engine_model.validation import InputError

STEADY_DEFAULT = ("customer_bleed", "hp_offtake", "reynolds", "inlet_loss", "nozzle_area")
# named to be tested (``--candidates``), not by default (package docstring)
MAP_CANDIDATES = ("map_scaling",)
SENSOR_DEFAULT = ("sensor_bias", "sensor_drift")
# parameters held at their default: identified only when the effect is present (docstring)
FIXED_NUISANCE = {"reynolds": ("flow_ratio",)}


@dataclass
class Candidate:
    """One effect instance: ``name`` (the instance name, e.g. ``sensor_bias_T48``),
    ``effect`` (its :class:`Effect` at neutral values), ``params`` (tested parameter names),
    ``lower`` / ``upper`` (bounds: the neutral value on a one-sided side, else +-inf),
    ``fixed`` (parameters held at their default), ``channel`` (sensor candidates),
    ``index`` (positions of ``params`` in the loop's global ``phi``), ``valid`` (n, 2): each
    parameter's documented valid range (``Param.valid``; +-inf where open): an estimate
    outside it is not this effect (:mod:`.confirm`)."""

    name: str
    effect: Effect
    params: tuple
    lower: np.ndarray
    upper: np.ndarray
    fixed: tuple = ()
    channel: str | None = None
    index: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    valid: np.ndarray | None = None

    def outside_valid(self, values) -> list:
        """The parameters whose ``values`` lie outside their valid range."""
        if self.valid is None:
            return []
        v = np.asarray(values, float)
        bad = (v < self.valid[:, 0]) | (v > self.valid[:, 1])
        return [q for q, b in zip(self.params, bad, strict=True) if b]

    @property
    def sensor(self) -> bool:
        return self.channel is not None

    @property
    def one_sided(self) -> np.ndarray:
        return np.isfinite(self.lower) | np.isfinite(self.upper)

    @property
    def registry_name(self) -> str:
        return self.effect.registry_name

    def spec(self, values) -> str:
        """The effect specification string with ``values`` of :attr:`params`."""
        kw = dict(self.effect.opts)
        kw.update({k: float(v) for k, v in zip(self.params, values, strict=True)})
        items = ",".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}"
                         for k, v in kw.items())
        return self.registry_name + (":" + items if items else "")


def _make(effect: Effect, channel=None) -> Candidate:
    fixed = FIXED_NUISANCE.get(effect.registry_name, ())
    params, lo, hi, valid = [], [], [], []
    for q in effect.params:
        if q.kind != "model" or q.name in fixed:
            continue
        params.append(q.name)
        r = q.range
        lo.append(q.default if r is not None and r[0] == q.default else -np.inf)
        hi.append(q.default if r is not None and r[1] == q.default else np.inf)
        v = q.valid or (None, None)
        valid.append((-np.inf if v[0] is None else v[0], np.inf if v[1] is None else v[1]))
    return Candidate(effect.name, effect, tuple(params), np.array(lo), np.array(hi),
                     tuple(fixed), channel, valid=np.array(valid, float).reshape(-1, 2))


def check_names(names=None, what: str = "--candidates") -> tuple:
    """The registry names to test (default: the library's), each checked: known, and not a
    series effect; ``what`` names the option in a message."""
    reg = registry()
    tested_names = tuple(names) if names is not None else STEADY_DEFAULT + SENSOR_DEFAULT
    if not tested_names:
        raise InputError(f"{what}: empty list")
    for n in tested_names:
        if n not in reg:
            raise InputError(f"{what}: unknown effect {n!r}; known: {', '.join(sorted(reg))}")
        if reg[n].series:
            raise InputError(f"{what}: {n} is a series effect (it acts on the time series, not "
                             "on the steady model); it cannot be score-tested")
        if n in NOT_CANDIDATES:
            raise InputError(f"{what}: {n} {NOT_CANDIDATES[n]}")
    return tested_names


#: Registered steady effects the loop refuses to test, with the reason. ``design_scaling``
#: is a constant efficiency and flow scaler of a component, the same thing as that
#: component's health parameters: the loop's θ per cycle absorbs it entirely, so its score
#: is zero by construction (:mod:`calibration.adaptation` fits it apart from θ, over a fleet).
NOT_CANDIDATES = {
    "design_scaling": "is the constant part of a map's adaptation, the same as the health "
                      "parameters the loop estimates per cycle; fit it with `hyprog adapt`",
}


def components(cls) -> tuple:
    """The components a per-component effect class is instantiated on: its ``MOVES``'s keys
    where it declares them (``map_slope`` and ``map_pressure_ratio`` exist for the
    compressors only), otherwise every component with health modifiers."""
    return tuple(getattr(cls, "MOVES", None) or COMPONENT_MODS)


def instantiate(name: str, sensors=()) -> list[Candidate]:
    """The candidates of one registered effect ``name``: one per channel of ``sensors`` for a
    sensor effect, one per component (:func:`components`) for a per-component effect, else
    one."""
    cls = registry()[name]
    if issubclass(cls, SensorEffect):
        return [_make(parse_effect_spec(f"{name}:channel={c}"), c) for c in sensors]
    if "component" in cls.options:  # map adaptation: one instance per component
        return [_make(parse_effect_spec(f"{name}:component={c}")) for c in components(cls)]
    return [_make(parse_effect_spec(name))]


def number(candidates: list[Candidate]) -> list[Candidate]:
    """``candidates`` with ``index`` set: consecutive slices of one global ``phi``."""
    k = 0
    for c in candidates:
        c.index = np.arange(k, k + len(c.params))
        k += len(c.params)
    return candidates


def build_candidates(names=None, sensors=(), has_cycle=True):
    """``(model_candidates, tested)``: every candidate the model carries (the library's
    steady effects, the sensor effects on every channel of ``sensors``, plus any other
    registered effect named) and the ones to test (``names``, registry names; default all).

    The model always carries the library's candidates so that one compiled variant serves
    every choice of ``--candidates``; an untested candidate stays at its neutral value. A
    sensor effect (a subclass of :class:`~engine_model.physics.effect_library.SensorEffect`) is
    instantiated on every sensor; an effect whose parameters need the ``cycle`` context is
    left out when the data have no cycles; series effects (``dynamics``) act on time series,
    not on ``p``, and are refused."""
    reg = registry()
    tested_names = check_names(names)
    carried = list(STEADY_DEFAULT) + [n for n in tested_names if n not in STEADY_DEFAULT
                                      and n not in SENSOR_DEFAULT] + list(SENSOR_DEFAULT)
    out = []
    for n in carried:
        needs_cycle = any(q.kind == "context" for q in reg[n].params)
        if needs_cycle and not has_cycle:
            continue
        out += instantiate(n, sensors)
    number(out)
    tested = [c for c in out if c.registry_name in tested_names]
    if not tested:
        raise InputError("--candidates: no candidate effect to test on these data")
    return out, tested


def steady_effects(names=None, values: dict | None = None) -> list:
    """The steady effects that :func:`build_candidates` puts into the candidate model for
    ``names``, in its order, with ``values`` (``{instance name: {parameter: value}}``, e.g.
    ``{"map_scaling_HPC": {"eff_1": 0.05}}``) switched on: a truth model built from them is
    the candidate model's compiled variant (the same names, the same C code)."""
    reg = registry()
    tested_names = check_names(names)
    values = values or {}
    out = []
    for n in list(STEADY_DEFAULT) + [n for n in tested_names if n not in STEADY_DEFAULT
                                     and n not in SENSOR_DEFAULT]:
        cls = reg[n]
        if issubclass(cls, SensorEffect) or any(q.kind == "context" for q in cls.params):
            continue
        opts = ([f"component={c}" for c in components(cls)] if "component" in cls.options
                else [""])
        for o in opts:
            inst = parse_effect_spec(n + (":" + o if o else ""))
            v = values.get(inst.name, {})
            if v:
                items = [o] if o else []
                items += [f"{k}={x!r}" for k, x in v.items()]
                inst = parse_effect_spec(n + ":" + ",".join(items))
            out.append(inst)
    unknown = set(values) - {e.name for e in out}
    if unknown:
        raise InputError(f"steady_effects: no carried effect named {', '.join(sorted(unknown))}")
    return out


@dataclass
class Evaluation:
    """The model at the current parameters, for the sensors used: ``y`` (N, m) readings,
    ``x`` (N, n_x) unknowns, ``converged`` (N,), ``d_theta`` (N, m, k) and ``d_phi``
    (N, m, n_phi) exact derivatives (when asked for)."""

    y: np.ndarray
    x: np.ndarray
    converged: np.ndarray
    d_theta: np.ndarray | None = None
    d_phi: np.ndarray | None = None


class CandidateModel:
    """Every candidate of ``candidates`` on top of ``design``: solves, readings and exact
    sensitivities with respect to the estimated theta and every candidate parameter.

    ``phi`` is the loop's global vector (zeros: the base model). Sensor effects are applied
    in candidate order after the steady solve."""

    def __init__(self, candidates: list[Candidate], design=None, compiled: bool = True,
                 model=None, fixed=(), sens_outputs=None):
        from engine_model import EngineModel

        self.candidates = candidates
        self.n_phi = int(sum(len(c.params) for c in candidates))
        steady = [c for c in candidates if not c.sensor]
        self.steady = steady
        self.sensor = [c for c in candidates if c.sensor]
        # ``fixed``: effects held at their values under every candidate (an adapted model)
        self.fixed = list(fixed)
        if model is not None and (steady or self.fixed):
            raise InputError("CandidateModel: a given model serves no steady candidate")
        # no steady candidate: the given (base) model as it is, no variant to build
        effects = [*self.fixed, *(c.effect for c in steady)]
        # ``sens_outputs``: the only channels ever read with derivatives (an adaptation's
        # fitted channels): the model computes no other output's sensitivities, which are
        # most of a fit's time (two thirds of an adaptation's)
        self.model = model if model is not None else EngineModel(
            design=design, effects=effects, compiled=compiled, sens_outputs=sens_outputs)
        self._set = EffectSet(effects)
        names = list(self._set.param_names)
        # global phi index -> column of the steady model's p
        self._steady_cols = []
        for c in steady:
            self._steady_cols.append(np.array([names.index(f"{c.name}.{q}") for q in c.params]))
        self._sensor_idx = (np.concatenate([c.index for c in self.sensor]).astype(int)
                            if self.sensor else np.zeros(0, int))
        self._readers: dict = {}

    def _sensor_rows(self, sensors: tuple) -> np.ndarray:
        """For every sensor parameter, the row of its channel in ``sensors`` (-1: absent)."""
        return np.array([sensors.index(c.channel) if c.channel in sensors else -1
                         for c in self.sensor for _ in c.params], int)

    def _reader(self, sensors: tuple):
        """One CasADi Function applying every sensor candidate on ``sensors`` in order, with
        exact derivatives (:func:`_sensor_reader`)."""
        if sensors not in self._readers:
            self._readers[sensors] = _sensor_reader(self.sensor, sensors)
        return self._readers[sensors]

    def p_steady(self, phi, n: int, cycle=None) -> np.ndarray:
        ctx = {"cycle": cycle} if cycle is not None else None
        P = self._set.p_matrix(n, context=ctx)
        for c, cols in zip(self.steady, self._steady_cols, strict=True):
            P[:, cols] = np.asarray(phi, float)[c.index]
        return P

    def evaluate(self, w, theta_full, sensors, phi, x0=None, cycle=None, est_idx=None,
                 derivatives: bool = False) -> Evaluation:
        """Solve (warm-started from ``x0`` when given) and return readings of ``sensors``;
        with ``derivatives``, ``d_theta`` for the columns ``est_idx`` of theta and
        ``d_phi`` for every candidate parameter."""
        n = len(w)
        P = self.p_steady(phi, n, cycle)
        m = self.model
        if x0 is None:
            res = m.solve_series(w, theta_full, P)
        else:
            res = m.solve_from(w, theta_full, x0, P)
        cols = [OUTPUT_NAMES.index(s) for s in sensors]
        F = m.outputs_at(res.x, w, theta_full, P)[:, cols]
        y = F.copy()
        dth = dph = None
        if derivatives:
            s = m.sensitivities_of(res.x, w, theta_full, P, tuple(sensors))
            est_idx = np.arange(len(THETA_NAMES)) if est_idx is None else est_idx
            dth = s.theta[:, :, est_idx]
            dph = np.zeros((n, len(sensors), self.n_phi))
            for c, pc in zip(self.steady, self._steady_cols, strict=True):
                dph[:, :, c.index] = s.p[:, :, pc]
        # sensor effects, in candidate order: y_c <- reading(y_c, phi_j), one mapped call
        if self.sensor:
            reader = self._reader(tuple(sensors))
            ph = np.asarray(phi, float)[self._sensor_idx]
            cyc = np.zeros(n) if cycle is None else np.asarray(cycle, float)
            fm = reader.map(n)
            r, dv, dp = fm(F.T, np.tile(ph[:, None], (1, n)), cyc.reshape(1, n))
            y = np.asarray(r).T.copy()
            if derivatives:
                dv = np.asarray(dv).T  # (N, m): dy_j / dF_j (a sensor effect keeps to its channel)
                dp = np.asarray(dp).T  # (N, n_s): d(reading of its channel) / d phi_k
                dth = dth * dv[:, :, None]
                dph = dph * dv[:, :, None]
                rows = self._sensor_rows(tuple(sensors))
                has = rows >= 0
                dph[:, rows[has], self._sensor_idx[has]] += dp[:, has]
        bad = ~res.converged
        y[bad] = np.nan
        return Evaluation(y=y, x=res.x, converged=res.converged, d_theta=dth, d_phi=dph)


def _sensor_reader(cands: list, sensors: tuple) -> ca.Function:
    """The readings of ``sensors`` with every sensor candidate of ``cands`` applied in order
    through its effect's ``apply`` on the hook ``sensor:<channel>`` (differentiated by
    CasADi): ``(F, phi_s, cycle) -> (y, dy_j/dF_j, d y_channel(k) / d phi_k)``; a context
    parameter (``cycle``) is the third input. A sensor effect changes only its own channel's
    reading, so both derivatives are vectors."""
    F = ca.SX.sym("F", len(sensors))
    cyc = ca.SX.sym("cycle")
    n_p = int(sum(len(c.params) for c in cands))
    P = ca.SX.sym("phi", n_p)
    y = [F[j] for j in range(len(sensors))]
    k = 0
    for c in cands:
        syms = {}
        for q in c.effect.params:
            if q.name in c.params:
                syms[q.name] = P[k + c.params.index(q.name)]
            elif q.kind == "context":
                syms[q.name] = cyc
            else:
                syms[q.name] = q.default
        k += len(c.params)
        if c.channel in sensors:
            j = sensors.index(c.channel)
            y[j] = c.effect.apply("sensor:" + c.channel, y[j], syms, {})
    Y = ca.vertcat(*y)
    dF = ca.vertcat(*[ca.jacobian(y[j], F[j]) for j in range(len(sensors))])
    own = []
    k = 0
    for c in cands:
        for i in range(len(c.params)):
            own.append(ca.jacobian(y[sensors.index(c.channel)], P[k + i])
                       if c.channel in sensors else ca.SX(0))
        k += len(c.params)
    dP = ca.vertcat(*own) if own else ca.SX(0, 1)
    return ca.Function("readings", [F, P, cyc], [Y, ca.densify(dF), ca.densify(dP)])
