"""The candidates a performance engineer uses to match a model to a real engine, each with a
prior and physical bounds.

Every candidate is one effect instance of the library (:mod:`engine_model.physics.effects`),
entered or left out as a whole (a *group* of parameters):

=====================  ====================================================================
group                  what it adapts
=====================  ====================================================================
design_scaling_<c>     the component's efficiency and flow level (design-point scaling)
map_scaling_<c>        their change with the component's corrected speed, linear and quadratic in
                       ``n_corr - 1`` (condition-dependent scaling: Li & Pilidis 2010; multi-point
                       adaptation: Tsoutsanis et al., Applied Energy 135, 2014)
map_slope_<k>          the slope of a compressor's speed lines (``k``: fan, LPC, HPC): the
                       pressure ratio's change along a speed line, which moves between
                       conditions at the same corrected speed (the bypass nozzle chokes
                       from take-off to cruise: C-MAPSS holds the corrected fan speed
                       at 2388 rpm in five of its six conditions)
customer_bleed         air taken off the HPC exit, and its change with altitude
hp_offtake             shaft power taken off the HP spool
reynolds               the loss of efficiency (and flow) at low Reynolds number index
inlet_loss             intake pressure loss, constant and ~ Mach^2
nozzle_area            the core and bypass nozzle throat areas
duct_loss              the bypass duct's, transition duct's and burner's pressure losses
                       (named with ``--candidates`` only)
cooling_flow           the HPT and LPT coolant fractions (named with ``--candidates`` only)
map_pressure_ratio_<k> the pressure-ratio scaler of a compressor's map, level and shape in
                       corrected speed (named with ``--candidates`` only; tried on FD002 and
                       not made a default: ``docs/adaptation.md``)
sensor_gain_<ch>       a sensor convention: the channel reads ``(1 + gain)`` times the
                       model's quantity (``sensor_bias`` with its offset held at zero: a
                       gain is scale-free and, unlike an offset, has a documented range)
=====================  ====================================================================

for ``c`` in fan, LPC, HPC, HPT, LPT and every fitted channel ``ch``.

Prior and bounds of every parameter: the prior std is the larger end of its *realistic*
range (``Param.range``, e.g. 4 % bleed, +-3 % on a design-point scaler), the bounds its
*valid* range (``Param.valid``), closed at the neutral value on a one-sided parameter (a
bleed cannot be negative). A fit that lands on a bound says so
(:meth:`.adapt.Adaptation.parameters`, ``at_bound``).
"""

from __future__ import annotations

import numpy as np

from calibration.discrepancy.candidates import STEADY_DEFAULT, Candidate, instantiate, number
from engine_model.validation import InputError

#: The levels: always fitted (:mod:`.selection`), not selected.
LEVEL_GROUP = "design_scaling"
#: The steady candidates, in the order they are carried.
STEADY_GROUPS = ("design_scaling", "map_scaling", "map_slope", *STEADY_DEFAULT)
#: Design-point quantities and a third map scaler a user may name (``--candidates``); not
#: among the defaults, which made the committed FD002 adaptation.
OPTIONAL_GROUPS = ("duct_loss", "cooling_flow", "map_pressure_ratio")
SENSOR_GROUP = "sensor_gain"


def _prior(effect, params) -> np.ndarray:
    out = []
    by_name = {q.name: q for q in effect.params}
    for name in params:
        q = by_name[name]
        r = q.range or (None, None)
        ends = [abs(v - q.default) for v in r if v is not None]
        out.append(max(ends) if ends and max(ends) > 0 else 1.0)
    return np.asarray(out, float)


def check_groups(names=None) -> tuple:
    """The candidate groups to use (default: every group but :data:`OPTIONAL_GROUPS`), each
    checked: known, named once, at least one. (Group names, not the discrepancy loop's
    effect names: :func:`calibration.discrepancy.candidates.check_names` checks those.)"""
    known = (*STEADY_GROUPS, *OPTIONAL_GROUPS, SENSOR_GROUP)
    names = tuple(names) if names is not None else (*STEADY_GROUPS, SENSOR_GROUP)
    if not names:
        raise InputError("--candidates: empty list")
    unknown = [n for n in names if n not in known]
    if unknown:
        raise InputError(f"--candidates: unknown candidate(s) {', '.join(unknown)}; known: "
                         f"{', '.join(known)}")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise InputError(f"--candidates: {', '.join(twice)} named twice")
    return names


def build_groups(channels, names=None) -> list[Candidate]:
    """Every candidate of ``names`` (registry names of :data:`STEADY_GROUPS` and
    ``sensor_gain``; default all), with ``index`` into one global ``phi`` and each
    candidate's ``prior`` attached."""
    names = check_groups(names)
    out = []
    for n in (*STEADY_GROUPS, *OPTIONAL_GROUPS):
        if n in names:
            out += instantiate(n)
    if SENSOR_GROUP in names:
        for c in instantiate("sensor_bias", channels):
            ch = c.channel
            keep = [i for i, q in enumerate(c.params) if q == "gain"]
            c.params = tuple(c.params[i] for i in keep)
            c.lower, c.upper, c.valid = c.lower[keep], c.upper[keep], c.valid[keep]
            c.fixed = ("offset",)
            c.name = f"{SENSOR_GROUP}_{ch}"
            out.append(c)
    for c in number(out):
        c.prior = _prior(c.effect, c.params)
    return out


def group_name(c: Candidate) -> str:
    """The group (``--candidates`` name) a candidate comes from: ``sensor_gain`` for a gain,
    else its effect's registry name."""
    return SENSOR_GROUP if c.name.startswith(SENSOR_GROUP + "_") else c.registry_name


def bounds(c: Candidate) -> tuple[np.ndarray, np.ndarray]:
    """``(lower, upper)`` of a candidate's parameters: the valid range, closed at the
    neutral value on a one-sided parameter."""
    lo = np.where(np.isfinite(c.lower), c.lower, c.valid[:, 0])
    hi = np.where(np.isfinite(c.upper), c.upper, c.valid[:, 1])
    return np.maximum(lo, c.valid[:, 0]), np.minimum(hi, c.valid[:, 1])
