"""Simulated units with one effect switched on in the truth: the data on which the loop is
tested and benchmarked (``tests/test_discrepancy*.py``, ``benchmarks/discrepancy.py``).

- A steady effect (customer bleed, off-take, Reynolds, inlet loss, nozzle area, map scaling)
  runs inside the steady state: the unit is simulated with the candidate model's variant that
  carries it (:func:`.candidates.steady_effects`: the same compiled code the loop fits, the
  effect at the given values), so the truth differs from the null model by the effect alone.
- A sensor effect (bias, drift) corrupts a reading, not the engine: the unit is simulated
  without noise, the effect applied to its channel (the drift with the row's flight
  ``cycle``), then the documented measurement noise added
  (:func:`engine_model.simulator.sensor_noise.add_noise`) from the generator seeded with ``(seed,
  unit, 99)``.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from engine_model import EngineModel
from engine_model.physics.effects import parse_effect_spec
from engine_model.simulator import fleet, sensor_noise

from .candidates import steady_effects


def unit_with_effect(base, spec: str, unit: int = 1, seed: int = 0,
                     preset: str = "tiny") -> tuple[pd.DataFrame, object]:
    """``(DataFrame, effect)``: unit ``unit`` of ``preset`` simulated with ``seed`` and the
    effect of the specification ``spec`` (e.g. ``"hp_offtake:P_kw=150"``) in the truth, on
    the engine ``base`` (module docstring)."""
    eff = parse_effect_spec(spec)
    if eff.name.startswith("sensor_"):
        df, _, _ = fleet.simulate(preset, units=[unit], seed=seed, model=base, noise_scale=0.0)
        ch = eff.channel
        p = {q.name: eff.values[q.name] for q in eff.params}
        if "cycle" in p:
            p["cycle"] = df["cycle"].to_numpy(float)
        df[ch] = eff.apply("sensor:" + ch, df[ch].to_numpy(float), p, {})
        rng = np.random.default_rng([seed, unit, 99])
        return sensor_noise.add_noise(df, rng), eff
    truth = EngineModel(design=base.design, effects=steady_effects(
        None, {eff.name: {q.name: eff.values[q.name] for q in eff.params}}))
    df, _, _ = fleet.simulate(preset, units=[unit], seed=seed, model=truth, effects=[eff])
    return df, eff
