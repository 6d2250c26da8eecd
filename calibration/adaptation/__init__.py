"""Adapt the engine model to a real fleet: what every engine shares apart from what each has.

The discrepancy loop (:mod:`calibration.discrepancy`) asks, unit by unit, whether an effect is
missing. A model that is simply not the real engine is missing something *every* engine of a
fleet shows, while health is each engine's own (manufacturing scatter when new, wear later).
This package fits the two apart on many engines at once, and keeps what generalises:

Each channel's noise per operating condition comes from the data
(:mod:`calibration.measurement_noise`: within engines, early life, the resolution a channel is
written to as a floor).

==============  ==========================================================================
module          job
==============  ==========================================================================
data            a fleet's early-life samples as arrays, each with its noise std
groups          the candidates: design-point and speed-dependent map scaling per
                component, bleed, off-take, Reynolds, intake loss, nozzle areas, sensor
                gains; each with a prior and its valid range as bounds
fleet_fit       the joint fit: shared parameters and every engine's health, bounded
                Gauss-Newton with exact (CasADi) Jacobians, Schur complement over engines
selection       forward selection judged by leaving each operating condition out, and the
                error on held-out engines
adapt           the whole run and its record; ``assess``: a recorded adaptation refitted
                to data, its errors with each condition left out and their std
artefact        the adapted model as a file that calibrate, discover and pipeline load
                (``--model-effects``)
==============  ==========================================================================

    from calibration.adaptation import adapt, write_adapted
    result = adapt(df)                       # a C-MAPSS table as hyprog import-cmapss reads it
    write_adapted(result.record(), Path("adapted.json"))

The data need ``unit``, ``cycle``, the operating settings ``alt Mach TRA T2``, a
``condition`` label (``hyprog data import-cmapss`` writes it) and the channels.
"""

from .adapt import Adaptation, adapt, assess
from .artefact import AdaptedModel, load_adapted, write_adapted

__all__ = ["Adaptation", "AdaptedModel", "adapt", "assess", "load_adapted", "write_adapted"]
