"""Extension point for optional physical effects (customer bleed, power off-take, Reynolds
effects, inlet loss, nozzle area change, sensor bias and drift, ...).

The cycle (:mod:`turbofan`) passes every quantity an effect may change through
``hook(name, value)``. An :class:`Effect` declares its parameters (names, units, defaults) and
rewrites the hooked quantities it cares about as CasADi expressions of its parameters, so
the effect is part of the same symbolic, differentiable model and its parameters can be
estimated jointly with theta. Hook names used by the cycle:

``P_amb``, ``P2``, ``<theta name>`` (the ten health deltas, e.g. ``HPT_eff_mod``), ``A18``,
``A8``, ``W_bleed_24`` (kg/s, default 0), ``W_customer_bleed`` (kg/s, default 0),
``P_offtake_HP`` (W, default 0), ``sensor:<channel>`` (every output, N-CMAPSS units).

A user registers an effect from their own code, without editing hyprog::

    class MyBias(Effect):
        name = "T48_bias"
        params = (Param("offset", "degR", 0.0),)
        def apply(self, hook, value, p, ctx):
            return value + p["offset"] if hook == "sensor:T48" else value

    register(MyBias)
    EngineModel(effects=[MyBias()])

The effect library itself is built in the fleet-simulator issue.
"""

from __future__ import annotations

from dataclasses import dataclass

_REGISTRY: dict[str, type] = {}


@dataclass(frozen=True)
class Param:
    name: str
    unit: str
    default: float
    description: str = ""


class Effect:
    """Base class: subclasses set ``name`` and ``params`` and implement :meth:`apply`."""

    name: str = ""
    params: tuple = ()
    description: str = ""

    def __init__(self, **values):
        known = {q.name for q in self.params}
        for k in values:
            if k not in known:
                raise ValueError(f"effect {self.name}: unknown parameter {k!r}"
                                 f" (known: {', '.join(sorted(known))})")
        self.values = {q.name: float(values.get(q.name, q.default)) for q in self.params}

    def apply(self, hook: str, value, p: dict, ctx: dict):
        return value


def register(cls: type) -> type:
    if not cls.name:
        raise ValueError("an effect needs a name")
    _REGISTRY[cls.name] = cls
    return cls


def registry() -> dict[str, type]:
    return dict(_REGISTRY)


class EffectSet:
    """The effects built into one model; maps their parameters onto the vector ``p``."""

    def __init__(self, effects=()):
        self.effects = list(effects)
        self.param_names = tuple(f"{e.name}.{q.name}" for e in self.effects for q in e.params)
        self.defaults = tuple(e.values[q.name] for e in self.effects for q in e.params)
        self.key = "_".join(e.name for e in self.effects)

    def hook(self, p, w):
        if not self.effects:
            return lambda name, value: value
        ctx = {"w": w}
        slices = {}
        k = 0
        for e in self.effects:
            slices[e.name] = {q.name: p[k + i] for i, q in enumerate(e.params)}
            k += len(e.params)

        def _hook(name, value):
            for e in self.effects:
                value = e.apply(name, value, slices[e.name], ctx)
            return value

        return _hook
