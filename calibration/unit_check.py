"""Is the data in the model's units? The model against the data before and after estimating.

A file in the wrong units can sit inside the flight envelope and hold positive readings (a
pressure in kPa, a temperature in K or degC, an altitude in metres), and an estimator then
pins theta at its bounds and reports a small standard deviation: a confident wrong answer.
So every unit's data are compared with the model before anything is estimated.

Before (:func:`check_units`): at the unit's first ``n_check`` samples (early life, where theta
is near the new engine's 0), the model is solved at ``theta = 0`` and, per measured channel,

- the ratio ``r = median(model / data)`` and
- the median normalised residual ``z = median |data - model| / sigma`` (the documented sensor
  noise of :mod:`engine_model.simulator.sensor_noise`)

are computed. A channel is an error (:class:`~engine_model.validation.InputError` naming the
unit, the channel and the likely unit) when

1. the data converted from a known wrong unit (:data:`CONVERSIONS`: psia vs kPa, Pa, bar;
   degR vs K, degC, degF; rpm vs rev/s, rad/s; lbm/s vs kg/s, lbm/h) agree with the model
   within ``UNIT_RTOL`` (5 %) while the data as given do not (they are off by more than
   ``MISMATCH_RTOL``, 10 %), or
2. ``z`` is above ``MAX_Z`` (100 sigma) *and* the median relative difference is above
   ``MISMATCH_RTOL`` (10 %) -- far beyond any wear (a 5 % efficiency loss moves a
   temperature by about 2 %) and beyond the model's own error against C-MAPSS (under 2 %).

An altitude in metres moves every pressure: when channels fail and the model solved at
``alt * 3.281`` (ft per m) agrees with the data, the error names the ``alt`` column. A
temperature ``T2`` in K or degC is outside the envelope (360-620 degR) and already refused by
:func:`engine_model.validation.check_w`.

After (:func:`check_result`): per channel, the median normalised residual of the estimate;
above ``MAX_Z`` it is a warning (the model cannot explain the channel whatever theta), and a
``theta_hat`` that ends at one of its bounds is a warning (the estimate is limited by the box,
not by the data; its reported std is then meaningless).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from engine_model.channels import OUTPUT_NAMES, UNITS, W_NAMES
from engine_model.units import (
    C_TO_K,
    F_TO_R,
    FT_TO_M,
    LBM_TO_KG,
    PSIA_TO_PA,
    R_PER_K,
    RPM_PER_REV_S,
)
from engine_model.validation import ENVELOPE, InputError

from .estimation_setup import CalibrationSetup
from .series import UnitSeries, error_prefix

N_CHECK = 200  # samples of early life compared with the model at theta = 0
UNIT_RTOL = 0.05  # converted data within 5 % of the model: the unit is found
MISMATCH_RTOL = 0.10  # data off the model by more than 10 %: not wear, not model error
MAX_Z = 100.0  # median |residual| / sigma above which a channel cannot be the model's
BOUND_TOL = 1e-4  # theta_hat within this of a bound is "at the bound"

# model unit -> [(the user's unit, data in that unit -> data in the model's unit)]
CONVERSIONS: dict[str, list[tuple[str, Callable[[np.ndarray], np.ndarray]]]] = {
    "psia": [("kPa", lambda y: y * 1e3 / PSIA_TO_PA), ("Pa", lambda y: y / PSIA_TO_PA),
             ("bar", lambda y: y * 1e5 / PSIA_TO_PA), ("MPa", lambda y: y * 1e6 / PSIA_TO_PA)],
    "degR": [("K", lambda y: y * R_PER_K), ("degC", lambda y: (y + C_TO_K) * R_PER_K),
             ("degF", lambda y: y + F_TO_R)],
    "rpm": [("rev/s", lambda y: y * RPM_PER_REV_S),
            ("rad/s", lambda y: y * RPM_PER_REV_S / (2 * np.pi))],
    "lbm/s": [("kg/s", lambda y: y / LBM_TO_KG), ("lbm/h", lambda y: y / 3600.0)],
}


@dataclass
class ChannelCheck:
    """One channel against the model: ``ratio`` median(model / data), ``z`` median
    |residual| / sigma, ``rel`` median |data / model - 1|, ``likely_unit`` the wrong unit that
    explains the data (None if none does)."""

    channel: str
    ratio: float
    z: float
    rel: float
    likely_unit: str | None = None

    @property
    def wrong(self) -> bool:
        return self.likely_unit is not None or (self.z > MAX_Z and self.rel > MISMATCH_RTOL)

    def as_dict(self) -> dict:
        return {"channel": self.channel, "ratio_model_to_data": self.ratio, "z": self.z,
                "rel": self.rel, "likely_unit": self.likely_unit}


def _early(series: UnitSeries, n_check: int) -> np.ndarray:
    """Row positions of the unit's first ``n_check`` samples (early life)."""
    return np.arange(min(len(series), n_check))


def model_outputs(model, w: np.ndarray, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All outputs (N, n_out) of ``model`` at ``w`` and full ``theta`` (N, 10), and the
    convergence flags."""
    sol = model.solve(w, theta)
    y = np.asarray(model.outputs_at(sol.x, w, theta), float)
    return y, np.asarray(sol.converged, bool)


def compare_channels(y: np.ndarray, y_model: np.ndarray, sigma: np.ndarray,
                     sensors) -> list[ChannelCheck]:
    """Per channel: ratio, normalised residual and the wrong unit that explains the data."""
    out = []
    for j, c in enumerate(sensors):
        d, m, s = y[:, j], y_model[:, j], sigma[:, j]
        ok = np.isfinite(m) & (d != 0)
        if not ok.any():
            continue
        d, m, s = d[ok], m[ok], s[ok]
        rel = float(np.median(np.abs(d / m - 1.0)))
        check = ChannelCheck(c, float(np.median(m / d)), float(np.median(np.abs(d - m) / s)),
                             rel)
        if rel > MISMATCH_RTOL:
            for unit, convert in CONVERSIONS.get(UNITS.get(c, ""), []):
                if float(np.median(np.abs(convert(d) / m - 1.0))) < UNIT_RTOL:
                    check.likely_unit = unit
                    break
        out.append(check)
    return out


def _alt_in_metres(model, series: UnitSeries, rows, setup: CalibrationSetup,
                   wrong: list[ChannelCheck]) -> bool:
    """True when the model at ``alt`` read as metres explains the failing channels."""
    w = series.w[rows].copy()
    j = W_NAMES.index("alt")
    w[:, j] = np.clip(w[:, j] / FT_TO_M, *ENVELOPE.alt_ft)
    if np.allclose(w[:, j], series.w[rows, j]):
        return False
    y_all, conv = model_outputs(model, w, setup.full_theta(np.zeros((len(rows), setup.k))))
    cols = [OUTPUT_NAMES.index(c) for c in series.sensors]
    checks = compare_channels(series.y[rows][conv], y_all[conv][:, cols],
                              series.sigma[rows][conv], series.sensors)
    fixed = {c.channel for c in checks if not c.wrong}
    return all(c.channel in fixed for c in wrong)


def check_units(model, series: UnitSeries, setup: CalibrationSetup, source=None,
                n_check: int = N_CHECK) -> list[ChannelCheck]:
    """The data of one unit against the model at theta = 0 (module docstring); raises
    InputError naming the unit, the channel(s) and the likely unit. Returns the checks."""
    return check_units_many(model, [series], setup, source, n_check)[0]


def check_units_many(model, series: Sequence[UnitSeries], setup: CalibrationSetup,
                     source=None, n_check: int = N_CHECK) -> list[list[ChannelCheck]]:
    """:func:`check_units` of every unit of ``series``, with one model solve for all of them:
    the units' first ``n_check`` samples are stacked and solved as independent series
    (``solve_series(..., starts=...)``: each unit warm-started along its own samples, none
    carried across units), then compared unit by unit, in order, so the first unit that fails
    raises, as one call each would. A fleet of short units (C-MAPSS) thus costs one model
    call instead of one per unit. Returns each unit's checks."""
    rows = [_early(s, n_check) for s in series]
    if not series:
        return []
    lengths = np.array([len(r) for r in rows])
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    w = np.concatenate([s.w[r] for s, r in zip(series, rows, strict=True)])
    theta = setup.full_theta(np.zeros((len(w), setup.k)))
    sol = model.solve_series(w, theta, starts=starts)
    y_all = np.asarray(model.outputs_at(sol.x, w, theta), float)
    conv_all = np.asarray(sol.converged, bool)
    out = []
    for s, r, a in zip(series, rows, starts, strict=True):
        sl = slice(a, a + len(r))
        out.append(_compare_unit(model, s, r, setup, source, y_all[sl], conv_all[sl]))
    return out


def _compare_unit(model, series: UnitSeries, rows, setup: CalibrationSetup, source,
                  y_all: np.ndarray, conv: np.ndarray) -> list[ChannelCheck]:
    """One unit's channels against the model outputs ``y_all`` at its ``rows`` (converged
    where ``conv``); raises InputError when a channel is wrong (module docstring)."""
    if not conv.any():
        return []  # nothing to compare; the estimator reports the non-converged samples
    cols = [OUTPUT_NAMES.index(c) for c in series.sensors]
    checks = compare_channels(series.y[rows][conv], y_all[conv][:, cols],
                              series.sigma[rows][conv], series.sensors)
    wrong = [c for c in checks if c.wrong]
    if not wrong:
        return checks
    where = error_prefix(series.unit, source)
    unexplained = [c for c in wrong if c.likely_unit is None]
    if len(unexplained) >= 2 and _alt_in_metres(model, series, rows, setup, unexplained):
        raise InputError(f"{where}column alt looks like metres (the model reads ft: the data"
                         f" match the model at alt x {1 / FT_TO_M:.3f}, not as given;"
                         f" channels {', '.join(c.channel for c in unexplained)} are off by"
                         f" {max(c.z for c in unexplained):.0f} sigma)")
    parts = []
    for likely in dict.fromkeys(c.likely_unit for c in wrong if c.likely_unit is not None):
        group = [c for c in wrong if c.likely_unit == likely]
        names = ", ".join(c.channel for c in group)
        ratios = "/".join(f"{c.ratio:.4g}" for c in group[:3]) + ("/..." if len(group) > 3
                                                                    else "")
        verb = "columns {} look" if len(group) > 1 else "column {} looks"
        parts.append(verb.format(names) +
                     f" like {likely} (the model reads {UNITS.get(group[0].channel, '')};"
                     f" model/data = {ratios})")
    for c in unexplained:
        parts.append(f"column {c.channel} is {c.z:.0f} sigma off the model at theta = 0"
                     f" (model/data = {c.ratio:.4g}; check its unit, the model reads"
                     f" {UNITS.get(c.channel, '')})")
    raise InputError(where + "; ".join(parts))


def check_result(result, unit, setup: CalibrationSetup) -> list[str]:
    """Warnings after estimating (module docstring): channels the estimate cannot explain
    and theta_hat ended at a bound. ``unit``: the unit's label for the messages (None: no
    label); the result holds everything else."""
    warns = []
    where = f"unit {unit}: " if unit is not None else ""
    z = np.abs(result.residuals.to_numpy(float))
    for j, c in enumerate(result.residuals.columns):
        col = z[:, j][np.isfinite(z[:, j])]
        if col.size and float(np.median(col)) > MAX_Z:
            warns.append(f"{where}channel {c}: median residual {float(np.median(col)):.0f}"
                         f" sigma after estimating; the model cannot explain it (check its"
                         f" unit, {UNITS.get(c, '')})")
    for hit in bound_hits(result, setup):
        warns.append(f"{where}{hit['param']} is at its bound {hit['bound']:g} at"
                     f" {hit['samples']} of {hit['of']} samples: {AT_BOUND}")
    return warns


AT_BOUND = "the box, not the data, sets it there (its std is not meaningful)"
#: Added when most of a fleet's units sit at one bound: a mismatch shared by the fleet, not
#: one engine's health (:func:`summarise_bound_hits`)
FLEET_AT_BOUND = ("most units at once: the model may not match this engine (adapt it to the "
                  "fleet with `hyprog adapt`, then calibrate with --model-effects; on measured "
                  "data also --noise data --model-error consistent)")


def bound_hits(result, setup: CalibrationSetup) -> list[dict]:
    """Every estimated parameter that ended at a bound of the box: ``{"param": "<q>_hat",
    "bound", "samples" (at it), "of" (the unit's samples)}``, in parameter order, lower
    bound first."""
    lo, hi = setup.bounds
    hits = []
    for name in result.theta_hat.columns:
        v = result.theta_hat[name].to_numpy(float)
        for bound, at in ((lo, v <= lo + BOUND_TOL), (hi, v >= hi - BOUND_TOL)):
            if at.any():
                hits.append({"param": name, "bound": float(bound), "samples": int(at.sum()),
                             "of": len(v)})
    return hits


def summarise_bound_hits(units: dict) -> list[str]:
    """One line per parameter and bound over a fleet: ``units`` maps a unit to its record
    with ``"at_bound"`` (:func:`bound_hits`) and ``"samples"``. What a reader of a 100-unit
    fleet needs instead of a line per unit (the per-unit lines stay in the JSON report). A
    bound hit in more than half of a fleet of at least two units adds
    :data:`FLEET_AT_BOUND`: degradation differs from engine to engine, a model mismatch does
    not."""
    grouped: dict[tuple, list] = {}
    for u, rec in units.items():
        for h in rec.get("at_bound", []):
            grouped.setdefault((h["param"], h["bound"]), []).append((u, h))
    lines = []
    for (param, bound), hits in grouped.items():
        k = sum(h["samples"] for _, h in hits)
        n = sum(h["of"] for _, h in hits)
        lines.append(f"{param} is at its bound {bound:g} in {len(hits)} of {len(units)} units"
                     f" ({_listed([u for u, _ in hits])}; {k:,} of their {n:,} samples): "
                     f"{AT_BOUND}")
        if len(units) >= 2 and 2 * len(hits) > len(units):
            lines[-1] += f"; {FLEET_AT_BOUND}"
    return lines


def fleet_warnings(warnings: list[str], units: dict) -> list[str]:
    """A fleet calibration's warnings as a reader gets them: ``warnings`` without the
    per-unit bound lines, then one line per parameter and bound over the fleet
    (:func:`summarise_bound_hits`; ``units`` as there). What ``hyprog calibrate`` prints
    (every unit's lines stay in its ``--json`` report) and ``hyprog pipeline`` reports."""
    per_unit = {w for v in units.values() for w in v.get("warnings", []) if w.endswith(AT_BOUND)}
    return [w for w in warnings if w not in per_unit] + summarise_bound_hits(units)


def _listed(units: list) -> str:
    """``unit 3`` or ``units 1, 2, 3, 4, 5, ...`` (the first five)."""
    names = [str(u) for u in units]
    return ("unit " if len(names) == 1 else "units ") + ", ".join(names[:5]) + \
        (", ..." if len(names) > 5 else "")


def summarise_unobservable(units: dict, prior_std: float) -> list[str]:
    """One line per set of unobservable parameters and sensors over a fleet: ``units`` maps a
    unit to its record with ``"unobservable"`` (the parameters held at the prior mean, see
    :mod:`calibration.observability`) and ``"sensors"``. A fleet of C-MAPSS units at one
    condition leaves the same parameters unobservable in every unit: one line, not one per
    unit (each unit's list stays in the JSON report)."""
    grouped: dict[tuple, list] = {}
    for u, rec in units.items():
        if rec.get("unobservable"):
            grouped.setdefault((tuple(rec["unobservable"]), tuple(rec.get("sensors", ()))),
                               []).append(u)
    return [f"health parameter(s) {', '.join(params)} cannot be observed with sensors "
            f"{', '.join(sensors)} in {len(us)} of {len(units)} units ({_listed(us)}: the "
            f"Fisher information is rank-deficient, or the data pin them down less than the "
            f"prior std {prior_std:g} does); held at the prior mean, reported as NaN"
            for (params, sensors), us in grouped.items()]


__all__ = ["ChannelCheck", "CONVERSIONS", "bound_hits", "check_result", "check_units",
           "check_units_many", "compare_channels", "fleet_warnings", "summarise_bound_hits",
           "summarise_unobservable"]
