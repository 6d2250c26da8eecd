"""Optional physical effects, the public façade: import effects from here.

An effect is an optional piece of physics (customer bleed, power off-take, Reynolds effects,
inlet loss, nozzle area change, sensor bias and drift, spool and thermal dynamics), off by
default, switched on by name with its own parameters. The pieces, imported one way only:

- :mod:`engine_model.physics.effect_base`: :class:`Param`, :class:`Effect`, :func:`register`,
  :class:`EffectSet`, :func:`apply_series` (the hooks and the parameter kinds are documented
  there);
- :mod:`engine_model.physics.effect_library`: the named effects, registered when it is imported;
- this module: both of them, plus the registry with the library loaded (:func:`registry`),
  :func:`parse_effect_spec` / :func:`effect_from_dict` (a specification string or dict ->
  an effect) and :func:`describe_effects` (``hyprog effects``).

Specification strings: ``NAME[:param=value,...]``, e.g. ``customer_bleed:f0=0.015`` or
``sensor_bias:channel=T48,offset=5``; options (``channel``) take strings, parameters numbers.
A bad specification raises :class:`EffectSpecError`, an
:class:`~engine_model.validation.InputError`.
"""

from __future__ import annotations

import math

from . import effect_library
from .effect_base import (
    PARAM_KINDS,
    Effect,
    EffectSet,
    EffectSpecError,
    Param,
    apply_series,
    register,
    registered,
    split_series_effects,
    unregister,
)

__all__ = [
    "PARAM_KINDS", "Param", "Effect", "EffectSpecError", "EffectSet", "register", "unregister",
    "registry", "parse_effect_spec", "effect_from_dict", "describe_effects", "apply_series",
    "split_series_effects", "effect_library",
]


def registry() -> dict[str, type]:
    """Every registered effect class by name (the library's and the user's)."""
    return registered()


def parse_effect_spec(spec: str) -> Effect:
    """``"NAME[:param=value,...]"`` -> an :class:`Effect` instance.

    Options (e.g. ``channel``) take strings, parameters numbers::

        parse_effect_spec("customer_bleed:f0=0.015")
        parse_effect_spec("sensor_bias:channel=T48,offset=5")

    Raises :class:`EffectSpecError` (an ``InputError``) naming the problem: an unknown effect
    (with the list of known ones), an unknown parameter (with the effect's parameters), a
    value that is not a number, an item that is not ``name=value``.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise EffectSpecError("empty effect specification; expected NAME[:param=value,...]")
    name, _, rest = spec.strip().partition(":")
    name = name.strip()
    reg = registry()
    if name not in reg:
        raise EffectSpecError(f"unknown effect {name!r} in {spec!r}; known effects: "
                              f"{', '.join(sorted(reg))}")
    cls = reg[name]
    numeric = {q.name for q in cls.params}
    options = set(cls.options)
    kwargs: dict = {}
    for item in (s for s in rest.split(",") if s.strip()) if rest else ():
        key, sep, text = item.partition("=")
        key, text = key.strip(), text.strip()
        if not sep or not key or not text:
            raise EffectSpecError(f"{spec!r}: {item.strip()!r} is not param=value")
        if key in kwargs:
            raise EffectSpecError(f"{spec!r}: {key!r} given more than once")
        if key in options:
            kwargs[key] = text
        elif key in numeric:
            try:
                value = float(text)
            except ValueError:
                raise EffectSpecError(f"{spec!r}: value of {key!r} must be a number, "
                                      f"got {text!r}") from None
            if not math.isfinite(value):
                raise EffectSpecError(f"{spec!r}: value of {key!r} must be finite")
            kwargs[key] = value
        else:
            known = sorted(options) + sorted(numeric)
            raise EffectSpecError(f"{spec!r}: effect {name} has no parameter {key!r}; "
                                  f"known: {', '.join(known) or 'none'}")
    return cls(**kwargs)


def effect_from_dict(d: dict) -> Effect:
    """Inverse of :meth:`Effect.to_dict`."""
    params = d.get("params") or {}
    items = ",".join(f"{k}={v}" for k, v in params.items())
    return parse_effect_spec(d["name"] + (":" + items if items else ""))


def describe_effects() -> list[dict]:
    """Every registered effect as a dict (sorted by name)::

        {"name": str, "kind": "steady" | "series", "description": str, "options": [str],
         "parameters": [{"name", "unit", "default", "typical", "range", "kind",
                         "description"}],
         "moves": [channel],                         # channels the effect changes
         "signature": {point: {channel: +1|-1|0}}}   # sign of the change at "typical" size
    """
    return [cls.describe() for _, cls in sorted(registry().items())]
