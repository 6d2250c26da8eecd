"""The base of optional physical effects: :class:`Param`, :class:`Effect`, the registry,
:class:`EffectSet` (the effects of one model and their parameter vector ``p``) and the series
effects' :func:`apply_series`.

This module imports nothing of hyprog but :mod:`validation`; the library of named effects
(:mod:`engine_model.physics.effect_library`) imports it and registers its classes, and
:mod:`engine_model.physics.effects` is the public façade over both (the registry with the library
loaded, :func:`~engine_model.physics.effects.parse_effect_spec`).

Two kinds of effect
-------------------
*Steady effects* (the default) change the steady-state model itself. The cycle
(:mod:`turbofan`) passes every quantity an effect may change through
``hook(name, value, **station)``. An :class:`Effect` declares its parameters (names, units,
defaults) and rewrites the hooked quantities it cares about as CasADi expressions of its
parameters, so the effect is part of the same symbolic, differentiable model and its
parameters can be estimated jointly with theta. With no effects every hook returns its input
unchanged, so the expression graph (and the compiled C code's hash) of the no-effect model does
not depend on this module.

*Series effects* (``series = True``, e.g. ``dynamics``) cannot be written as a change of the
steady state: they act on the time series of steady outputs of one flight after the steady
solve (:meth:`Effect.apply_series`, :func:`apply_series`). :class:`EffectSet` keeps them out of
the steady model's parameter vector ``p``.

Hooks
-----
Hook names used by the cycle, with the station context passed as keyword arguments (available
to :meth:`Effect.apply` in ``ctx``, next to ``ctx["w"]``, the symbolic ``[alt, Mach, TRA, T2]``):

=====================================  =========================================================
hook (value, unit)                     context keywords
=====================================  =========================================================
``P_amb`` (Pa)                         -
``<theta name>`` (fraction), e.g.      ``T_in`` [K], ``P_in`` [Pa]: the component's inlet total
``HPT_eff_mod``, ``fan_flow_mod``      state at this operating point; ``T_in_des``, ``P_in_des``:
                                       the same at the design point; ``eta_des``: the design
                                       efficiency (floats); ``n_corr``: the component's
                                       corrected speed relative to the SLS design point
                                       (compressors: their map's speed coordinate).
                                       Fan: T2 and the free-stream Pt0
                                       (the fan's hooks precede the intake loss); LPC: 21;
                                       HPC: 25; HPT: 41 / P40; LPT: 49 / P45.
``fan_slope_mod``, ``LPC_slope_mod``,  the same as the component's ``<theta name>`` hooks;
``HPC_slope_mod`` (fraction, default   scales the slope of the map's work line
0)                                     (:meth:`maps.CompressorMap.work`)
``fan_pr_mod``, ``LPC_pr_mod``,        the same; scales the map's isentropic head and work
``HPC_pr_mod`` (fraction, default 0)   by ``1 + value`` (:func:`components.compressor`)
``P2`` (Pa, fan face after the         ``Pt0`` [Pa] (free-stream total pressure)
intake loss)
``A18``, ``A8`` (m^2, nozzle throats)  -
``W_bleed_24`` (kg/s, default 0)       ``W22`` [kg/s]
``W_vbv`` (kg/s, the VBV schedule's    ``W22`` [kg/s], ``n_hpc``, ``n_fan`` (corrected core
bleed into the bypass duct)            and fan speeds, fractions of design)
``W_customer_bleed`` (kg/s, default 0) ``W25`` [kg/s] (HPC inlet flow), ``T30`` [K], ``P30`` [Pa]
``P_offtake_HP`` (W, default 0)        -
``dp_bypass``, ``dp_icd``,             -
``dp_burner`` (dP/P at design flow:
bypass duct, booster-HPC duct, burner)
``f31``, ``f32`` (HPT and LPT coolant  -
fractions of the HPC inlet flow)
``sensor:<channel>`` (every output,    -
N-CMAPSS units)
=====================================  =========================================================

Parameters
----------
A :class:`Param` has a name, a unit, a default (the *neutral* value: an effect at its defaults
leaves every output unchanged), a description, a realistic size (``typical``) and range
(``range``), and a ``kind``:

- ``kind="model"``: a physical parameter, one entry of ``p``, constant over a call unless the
  caller passes a per-row ``p`` matrix; these are what a calibration may estimate.
- ``kind="context"``: a per-row quantity that is not in ``w`` but that an effect needs, e.g. the
  flight ``cycle`` for a sensor drift. It is still an entry of ``p`` (so the model stays one
  CasADi Function of ``x, w, theta, p``), but its value is supplied row by row by the caller:
  :meth:`EffectSet.p_matrix` fills every context column from ``context={"cycle": ...}``; the
  fleet simulator sets ``cycle``. A calibration never estimates a context parameter
  (:attr:`EffectSet.estimable`).

A user registers an effect from their own code, without editing hyprog::

    class MyBias(Effect):
        name = "T48_bias"
        params = (Param("offset", "degR", 0.0),)
        def apply(self, hook, value, p, ctx):
            return value + p["offset"] if hook == "sensor:T48" else value

    register(MyBias)
    EngineModel(effects=[MyBias()])
    parse_effect_spec("T48_bias:offset=5")     # -> MyBias(offset=5)  (engine_model.physics.effects)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from engine_model.validation import InputError

_REGISTRY: dict[str, type] = {}

PARAM_KINDS = ("model", "context")


@dataclass(frozen=True)
class Param:
    """One parameter of an effect.

    ``default`` is the neutral value (the effect does nothing there); ``typical`` a realistic
    size for a fleet that has the effect; ``range`` the realistic range ``(lo, hi)``;
    ``valid`` the documented valid range ``(lo, hi)`` (either end may be None: unbounded):
    the values for which the model stays a physical engine; a value outside it is refused
    when the effect is made, before any model is built (:class:`EffectSpecError` naming the
    effect, the parameter and the range); ``kind`` ``"model"`` (physical, estimable) or
    ``"context"`` (supplied per row by the caller, e.g. ``cycle``).
    """

    name: str
    unit: str
    default: float
    description: str = ""
    typical: float | None = None
    range: tuple | None = None
    kind: str = "model"
    valid: tuple | None = None

    def __post_init__(self):
        if self.kind not in PARAM_KINDS:
            raise ValueError(f"parameter {self.name}: kind must be one of {PARAM_KINDS}")
        if self.valid is not None:
            lo, hi = self.valid
            if not ((lo is None or lo <= self.default) and (hi is None or self.default <= hi)):
                raise ValueError(f"parameter {self.name}: default {self.default} outside its"
                                 f" valid range {self.valid}")

    def check(self, effect: str, value: float) -> None:
        """``value`` inside :attr:`valid`, else an :class:`EffectSpecError`."""
        if self.valid is None:
            return
        lo, hi = self.valid
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            unit = "" if self.unit in ("-", "") else f" {self.unit}"
            raise EffectSpecError(f"effect {effect}: parameter {self.name} = {value:g} is"
                                  f" outside its valid range {valid_text(self.valid)}{unit}"
                                  " (see `hyprog effects`)")


def valid_text(valid: tuple | None) -> str:
    """``[lo, hi]`` with unbounded ends written as -inf / inf."""
    if valid is None:
        return "(-inf, inf)"
    lo, hi = valid
    return (f"{'(-inf' if lo is None else f'[{lo:g}'}, "
            f"{'inf)' if hi is None else f'{hi:g}]'}")


class EffectSpecError(InputError):
    """A bad effect specification (unknown effect, unknown parameter, bad value): a user's
    input error, so an :class:`~engine_model.validation.InputError` (and a ``ValueError``)."""


class Effect:
    """Base class: subclasses set ``name`` and ``params`` and implement :meth:`apply` (steady
    effects) or, with ``series = True``, :meth:`apply_series`.

    Class attributes
    ----------------
    name : str
        Registry name (``parse_effect_spec`` looks it up). An instance may carry a longer
        ``name`` (e.g. ``sensor_bias_T48``) so that two instances can live in one model; the
        registry name stays ``type(e).name``.
    params : tuple of Param
    options : tuple of str
        Non-numeric constructor options (e.g. ``channel``), given as ``option=value`` in a spec.
    description : str
    moves : tuple of str
        The measured channels (x_s) the effect moves by more than 0.1 % at its realistic
        (``typical``) size at sea-level static or cruise (``"<channel>"`` for the channel
        option); tested in ``tests/test_effects.py``.
    signature : dict
        ``{point label: {channel: +1 | -1 | 0}}`` at the effect's realistic size (see
        :mod:`engine_model.physics.effect_library`); 0 means unchanged within 1e-9 relative.
    series : bool
        True for an effect on the output time series (not part of the steady model).
    shape_params : tuple of str
        Parameters that shape the effect but do not size it (``reynolds``' ``flow_ratio``):
        with every other one at its neutral default the effect changes nothing
        (:meth:`is_neutral`).
    """

    name: str = ""
    params: tuple = ()
    options: tuple = ()
    description: str = ""
    moves: tuple = ()
    signature: dict = {}
    series: bool = False
    shape_params: tuple = ()

    def __init__(self, **values):
        known = {q.name for q in self.params}
        self.opts: dict[str, str] = {}
        for k in list(values):
            if k in self.options:
                self.opts[k] = str(values.pop(k)).strip()
            elif k not in known:
                raise EffectSpecError(
                    f"effect {self.name}: unknown parameter {k!r} (known: "
                    f"{', '.join(sorted(self.options) + sorted(known)) or 'none'})")
        self.values = {}
        for q in self.params:
            v = values.get(q.name, q.default)
            try:
                v = float(v)
            except (TypeError, ValueError):
                raise EffectSpecError(f"effect {self.name}: parameter {q.name!r} must be a"
                                      f" number, got {v!r}") from None
            if not math.isfinite(v):
                raise EffectSpecError(f"effect {self.name}: parameter {q.name!r} must be"
                                      f" finite, got {v!r}")
            q.check(self.name, v)
            if q.kind == "context" and v != q.default:
                raise EffectSpecError(f"effect {self.name}: {q.name} is supplied row by row "
                                      f"(a context parameter), not in the specification")
            self.values[q.name] = v

    # ---------------------------------------------------------------- steady effects
    def apply(self, hook: str, value, p: dict, ctx: dict):
        """Return ``value`` (the hooked quantity) as changed by this effect; ``p`` maps this
        effect's parameter names to their symbols; ``ctx`` holds ``w`` and the station context
        of the hook (see the module docstring)."""
        return value

    # ---------------------------------------------------------------- series effects
    def apply_series(self, df, values: dict | None = None):
        """Series effects: the output DataFrame of one or several flights, changed."""
        return df

    # ---------------------------------------------------------------- bookkeeping
    @property
    def registry_name(self) -> str:
        return type(self).name

    def spec(self) -> str:
        """The specification string that :func:`parse_effect_spec` turns back into an equal
        effect, e.g. ``sensor_bias:channel=T48,offset=5,gain=0``."""
        items = [f"{k}={v}" for k, v in self.opts.items()]
        items += [f"{k}={v:.17g}" for k, v in self.values.items()]
        return self.registry_name + (":" + ",".join(items) if items else "")

    def to_dict(self) -> dict:
        """``{"name": registry name, "params": {options and values}}`` (dataset metadata)."""
        return {"name": self.registry_name, "params": {**self.opts, **self.values}}

    def is_neutral(self) -> bool:
        """Every parameter that sizes the effect at its neutral default (the context and
        :attr:`shape_params` ones aside): the effect changes nothing."""
        return all(self.values[q.name] == q.default for q in self.params
                   if q.kind == "model" and q.name not in self.shape_params)

    def typical_spec(self) -> str:
        """This effect's specification with every model parameter at its typical size (the
        size to suggest when a request would inject nothing), options kept."""
        items = [f"{k}={v}" for k, v in self.opts.items()]
        items += [f"{q.name}={q.typical:g}" for q in self.params
                  if q.kind == "model" and q.typical is not None]
        return self.registry_name + (":" + ",".join(items) if items else "")

    def __repr__(self):
        return f"<Effect {self.spec()}>"

    @classmethod
    def describe(cls) -> dict:
        """Name, description, options, parameters (unit, default, realistic size and range,
        kind) and the channels the effect moves, as plain Python data."""
        return {
            "name": cls.name,
            "kind": "series" if cls.series else "steady",
            "description": " ".join(cls.description.split()),
            "options": list(cls.options),
            "parameters": [
                {"name": q.name, "unit": q.unit, "default": q.default, "typical": q.typical,
                 "range": list(q.range) if q.range is not None else None,
                 "valid": list(q.valid) if q.valid is not None else None, "kind": q.kind,
                 "description": q.description}
                for q in cls.params
            ],
            "moves": list(cls.moves),
            "signature": {k: dict(v) for k, v in cls.signature.items()},
        }


def register(cls: type) -> type:
    """Add an :class:`Effect` subclass to the registry under ``cls.name`` (usable as a class
    decorator). Registering a name again replaces the earlier class."""
    if not isinstance(cls, type) or not issubclass(cls, Effect):
        raise TypeError("register() takes an Effect subclass")
    if not cls.name or not str(cls.name).isidentifier():
        raise ValueError(f"an effect needs a name that is an identifier, got {cls.name!r}")
    names = [q.name for q in cls.params] + list(cls.options)
    if len(set(names)) != len(names):
        raise ValueError(f"effect {cls.name}: duplicate parameter or option names")
    _REGISTRY[cls.name] = cls
    return cls


def unregister(name: str) -> type | None:
    """Remove the effect registered under ``name``; returns its class (None if there was
    none)."""
    return _REGISTRY.pop(name, None)


def registered() -> dict[str, type]:
    """The effect classes registered so far, by name. :func:`engine_model.physics.effects.registry`
    is the same with the library's effects loaded."""
    return dict(_REGISTRY)


class EffectSet:
    """The effects built into one model; maps their parameters onto the vector ``p``.

    Steady effects (``series = False``) are part of the model: their parameters are ``p``, in
    order, named ``<effect name>.<param>``. Series effects are kept in :attr:`series` and
    applied to the outputs afterwards (:func:`apply_series`).
    """

    def __init__(self, effects=()):
        effects = list(effects)
        for e in effects:
            if not isinstance(e, Effect):
                raise TypeError(f"not an Effect: {e!r} (use parse_effect_spec for strings)")
        names = [e.name for e in effects]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise EffectSpecError(f"effect {dup[0]!r} given more than once; give instances "
                                  "distinct names (e.g. sensor_bias on different channels)")
        self.effects = [e for e in effects if not e.series]
        self.series = [e for e in effects if e.series]
        self.param_names = tuple(f"{e.name}.{q.name}" for e in self.effects for q in e.params)
        self.defaults = tuple(e.values[q.name] for e in self.effects for q in e.params)
        flat = [q for e in self.effects for q in e.params]
        # column of p -> context key, for the context parameters (supplied per row)
        self.context = {i: q.name for i, q in enumerate(flat) if q.kind == "context"}
        self.estimable = tuple(n for n, q in zip(self.param_names, flat, strict=True)
                               if q.kind == "model")
        self.key = "_".join(e.name for e in self.effects)

    def p_matrix(self, n: int, values: dict | None = None, context: dict | None = None):
        """The (n, len(p)) parameter matrix: the defaults, overridden by ``values``
        (``{"<effect>.<param>": value or (n,) array}``), with every context column filled
        from ``context`` (``{"cycle": (n,) array}``; a context parameter not in ``context``
        keeps its default)."""
        import numpy as np

        P = np.tile(np.asarray(self.defaults, float), (n, 1)).reshape(n, len(self.defaults))
        for k, v in (values or {}).items():
            if k not in self.param_names:
                raise KeyError(f"no effect parameter {k!r}; parameters: "
                               f"{', '.join(self.param_names) or 'none'}")
            P[:, self.param_names.index(k)] = v
        for i, key in self.context.items():
            if context is not None and key in context:
                P[:, i] = np.asarray(context[key], float)
        return P

    def hook(self, p, w):
        if not self.effects:
            return _identity_hook
        base = {"w": w}
        slices = {}
        k = 0
        for e in self.effects:
            slices[e.name] = {q.name: p[k + i] for i, q in enumerate(e.params)}
            k += len(e.params)

        def _hook(name, value, **station):
            ctx = {**base, **station} if station else base
            for e in self.effects:
                value = e.apply(name, value, slices[e.name], ctx)
            return value

        return _hook


def _identity_hook(name, value, **station):
    return value


def split_series_effects(effects):
    """``(steady, series)``: the effects that are part of the steady model and those applied
    to the output time series afterwards."""
    effects = list(effects)
    return ([e for e in effects if not e.series], [e for e in effects if e.series])


def apply_series(effects, df, values: dict | None = None):
    """Apply the series effects among ``effects`` (instances, or an :class:`EffectSet`) to the
    steady outputs ``df`` of one or several flights, in order; steady effects are skipped
    (they are already in the steady solve). ``values`` optionally overrides parameters per
    effect: ``{"dynamics": {"tau_spool": 2.0}}``. Returns a new DataFrame."""
    if isinstance(effects, EffectSet):
        effects = effects.series
    for e in effects:
        if getattr(e, "series", False):
            df = e.apply_series(df, (values or {}).get(e.name))
    return df
