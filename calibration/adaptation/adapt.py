"""``adapt``: the whole adaptation of the engine model to a fleet's measured data, and its
record (:mod:`.artefact`). The steps are the package docstring's."""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import pandas as pd

from engine_model.channels import THETA_NAMES
from engine_model.datasets import hyprog_version
from engine_model.datasets.fingerprint import rows_fingerprint
from engine_model.physics.effects import EffectSpecError, parse_effect_spec
from engine_model.validation import InputError

from ..measurement_noise import EARLY_CYCLES
from .data import DEFAULT_CHANNELS, MODEL_ERROR, fleet_data
from .fleet_fit import FleetData, FleetFit, Shared, fit_fleet
from .groups import (
    OPTIONAL_GROUPS,
    SENSOR_GROUP,
    STEADY_GROUPS,
    bounds,
    build_groups,
    group_name,
)
from .selection import (
    TOP,
    OutOfSample,
    Selection,
    condition_out,
    engines_out,
    mean_errors,
    select,
    shared_of,
)


def fitted_parameters(groups, chosen, fit) -> list[dict]:
    """Every parameter of the ``chosen`` candidates among ``groups`` in ``fit``: candidate,
    parameter, value, posterior std, the range the fit bounded it to (:func:`.groups.bounds`:
    the valid range, closed at the neutral value on a one-sided parameter), and whether it
    sits on a bound of that range (``at_bound``). The std of a parameter on a bound is the
    curvature's at the optimum, as if the bound were not there: it says how far the data
    would move the parameter, not that the bound is uncertain."""
    std = fit.std
    out, k = [], 0
    for c in groups:
        if c.name not in chosen:
            continue
        lows, highs = bounds(c)
        for j, q in enumerate(c.params):
            v = float(fit.phi[c.index[j]])
            lo, hi = float(lows[j]), float(highs[j])
            out.append({"candidate": c.name, "parameter": q, "value": v,
                        "std": float(std[k]) if k < len(std) else float("nan"),
                        "valid": [lo, hi],
                        "at_bound": bool(np.isclose(v, lo) or np.isclose(v, hi))})
            k += 1
    return out


def effect_specs(groups, chosen, phi) -> list[str]:
    """The ``chosen`` candidates among ``groups`` as effect specifications at ``phi``, each
    checked as :func:`~calibration.adaptation.artefact.load_adapted` will check it. The fit
    bounds every parameter on its own, not their combinations: a customer bleed whose fitted
    schedule is negative at the ceiling (``f0 + 4.5 f_alt < 0``) is refused here, with its
    values, rather than written into a model no command could load."""
    specs = [c.spec(phi[c.index]) for c in groups if c.name in chosen]
    for s in specs:
        try:
            parse_effect_spec(s)
        except EffectSpecError as exc:
            raise InputError(f"the adapted model cannot be written: {s}: {exc}") from None
    return specs


@dataclass
class Adaptation:
    """The result: the selection, the data it used, the noise table, the held-out-engine
    errors before and after, and :meth:`record` (the artefact's content)."""

    selection: Selection
    data: FleetData
    noise: pd.DataFrame
    groups: list
    engines_out_before: float
    engines_out_after: float
    seconds: float
    source: dict

    def parameters(self) -> list[dict]:
        """Every fitted parameter (:func:`fitted_parameters`)."""
        return fitted_parameters(self.groups, self.selection.chosen, self.selection.fit)

    def effects(self) -> list[str]:
        """The chosen candidates as checked effect specifications (:func:`effect_specs`)."""
        return effect_specs(self.groups, self.selection.chosen, self.selection.fit.phi)

    def theta_summary(self, fit: FleetFit) -> dict:
        """Early-life health of the engines under ``fit``: mean and std across engines of
        every parameter of ``delta``."""
        return {q: {"mean": float(fit.delta[:, j].mean()), "std": float(fit.delta[:, j].std())}
                for j, q in enumerate(THETA_NAMES)}

    def discrepancy_pct(self, fit: FleetFit) -> dict | None:
        """Condition -> channel -> the model's own error there as the fit sees it, ``-b``
        (:mod:`.fleet_fit`: model minus reading, the sign of ``mean_error_pct``) in % of the
        channel's mean reading at the condition; None when the model error was not
        shared."""
        if fit.discrepancy is None:
            return None
        out = {}
        for c, b in zip(fit.discrepancy_conditions, fit.discrepancy, strict=True):
            y = self.data.y[self.data.condition == c].mean(axis=0)
            out[int(c)] = {ch: float(-100.0 * b[j] / y[j])
                           for j, ch in enumerate(self.data.channels)}
        return out

    def record(self) -> dict:
        sel = self.selection
        return {
            "effects": self.effects(),
            "parameters": self.parameters(),
            "channels": list(self.data.channels),
            "noise": {str(k): {c: float(v) for c, v in row.items()}
                      for k, row in self.noise.iterrows()},
            "data": self.source,
            "selection": {
                "steps": [vars(s) for s in sel.steps],
                "chosen": list(sel.chosen),
                "stopped": sel.stopped,
                "chi2_in_sample": {"before": sel.base_fit.chi2_per_sample(),
                                   "after": sel.fit.chi2_per_sample()},
                "chi2_condition_out": {"before": sel.before.chi2_out,
                                       "after": sel.after.chi2_out},
                "chi2_engines_out": {"before": self.engines_out_before,
                                     "after": self.engines_out_after},
                "mean_error_pct_in_sample": {
                    "before": mean_errors(self.data, sel.base_fit.prediction,
                                          sel.base_fit.converged),
                    "after": mean_errors(self.data, sel.fit.prediction, sel.fit.converged)},
                "mean_error_pct_condition_out": {"before": sel.before.mean_error_pct,
                                                 "after": sel.after.mean_error_pct},
                "unusable_condition_out": {"before": sel.before.unusable,
                                           "after": sel.after.unusable},
                "iterations_condition_out": {"before": sel.before.iterations,
                                             "after": sel.after.iterations},
                "std_pct_condition_out": {"before": sel.before.std_pct,
                                          "after": sel.after.std_pct},
                "theta_early_life": {"before": self.theta_summary(sel.base_fit),
                                     "after": self.theta_summary(sel.fit)},
                "discrepancy_pct": {"before": self.discrepancy_pct(sel.base_fit),
                                    "after": self.discrepancy_pct(sel.fit)},
            },
            "seconds": self.seconds,
            "hyprog_version": hyprog_version(),
        }


def adapt(df: pd.DataFrame, channels=DEFAULT_CHANNELS, candidates=None,
          early_cycles: int = EARLY_CYCLES, units=None, model=None, log=None,
          source: str = "data", engine_folds: int = 3, seed: int = 0,
          model_error: float = MODEL_ERROR, judge: int = TOP,
          model_error_shared: bool | None = None) -> Adaptation:
    """Adapt the engine model to the fleet in ``df`` (package docstring). ``candidates``:
    registry names of :mod:`.groups` (default all); ``model``: a prebuilt
    :class:`~calibration.discrepancy.candidates.CandidateModel` whose candidates include
    these (:func:`prebuilt_groups`: one model for several adaptations);
    ``model_error``: the model's relative error in each sample's std (:mod:`.data`),
    shared by each condition's samples unless ``model_error_shared`` is False (None: the
    default of :func:`.data.fleet_data`; :mod:`.fleet_fit`);
    ``judge``: candidates judged out of sample per step (:data:`.selection.TOP`)."""
    from calibration.discrepancy.candidates import CandidateModel

    t0 = time.perf_counter()
    if judge < 1 or engine_folds < 2:
        raise InputError(f"judge must be at least 1 and engine folds at least 2, got {judge} "
                         f"and {engine_folds}")
    data, noise = fleet_data(df, channels, early_cycles, units, source=source,
                             model_error=model_error, shared_model_error=model_error_shared)
    check_fleet(data, source, engine_folds)
    groups = build_groups(data.channels, candidates)
    if model is None:
        model = CandidateModel(groups, sens_outputs=data.channels)
    else:
        groups = prebuilt_groups(model, [c.name for c in groups])
    sel = select(model, data, groups, log, judge=judge)
    before = engines_out(model, data, Shared.none(), sel.base_fit, engine_folds, seed)
    after = engines_out(model, data, shared_of(groups, sel.chosen), sel.fit, engine_folds,
                        seed)
    early = df[(df["cycle"] <= early_cycles) & df["unit"].isin(data.units)]
    info = {"path": source, "fingerprint": rows_fingerprint(early), "units": data.n_units,
            "unit_list": list(data.units), "samples": len(data.y),
            "early_cycles": early_cycles, "model_error": model_error,
            "model_error_shared": data.shared_error, "judge": judge,
            "candidates": sorted({group_name(g) for g in groups}),
            "engine_folds": engine_folds, "seed": seed}
    return Adaptation(sel, data, noise, groups, before, after, time.perf_counter() - t0, info)


def prebuilt_groups(model, names, what: str = "candidate") -> list:
    """The candidates ``names`` as they are in the prebuilt ``model``, which indexes their
    parameters in its own ``phi`` (a model built for more candidates than an adaptation
    selects among or a record chose; the others stay at 0, which leaves the engine as it
    is). Refused, naming them (as ``what``), when the model lacks any."""
    have = {c.name: c for c in model.candidates}
    missing = sorted(set(names) - set(have))
    if missing:
        raise InputError(f"the prebuilt model lacks {what}(s) {', '.join(missing)}")
    return [have[n] for n in names]


def check_fleet(data: FleetData, source: str, engine_folds: int = 2) -> None:
    """Refuse, before any fit, a fleet the adaptation cannot judge: fewer than two operating
    conditions (each is left out in turn) or fewer engines than ``engine_folds`` (engines are
    held out in folds)."""
    if len(np.unique(data.condition)) < 2:
        raise InputError(f"{source}: one operating condition in the early-life rows; the "
                         "adaptation leaves each condition out in turn and needs two or more "
                         "(C-MAPSS FD002 and FD004 have six)")
    if data.n_units < engine_folds:
        raise InputError(f"{source}: {data.n_units} engine(s) in the early-life rows; the "
                         f"adaptation holds engines out in {engine_folds} folds and needs at "
                         f"least {engine_folds}")


def record_groups(record: dict, channels, source: str = "the adapted model") -> list:
    """The candidate groups of a record's chosen candidates (:mod:`.groups`, the optional
    ones included), for the record's ``channels``, in the library's order; a chosen name
    no group has is refused."""
    chosen = set(record["selection"]["chosen"])
    every = build_groups(channels, (*STEADY_GROUPS, *OPTIONAL_GROUPS, SENSOR_GROUP))
    unknown = sorted(chosen - {c.name for c in every})
    if unknown:
        raise InputError(f"{source}: chosen candidate(s) {', '.join(unknown)} are not "
                         f"candidates of the channels {', '.join(channels)}")
    names = sorted({group_name(c) for c in every if c.name in chosen})
    return build_groups(channels, names) if names else []


def assess(df: pd.DataFrame, record: dict, units=None, model=None,
           source: str = "data", design=None) -> tuple[FleetFit, OutOfSample]:
    """An adapted model's record (:mod:`.artefact`) refitted to the early life of ``units`` of
    ``df`` with its own choices (channels, early cycles, model error, chosen candidates; a
    record without ``data.model_error`` was fitted with the noise alone, as every record was
    before the option existed, and is refitted so; one without ``data.model_error_shared``
    counted it per sample), started at its recorded values: the fit
    and the errors with each condition left out, with their std
    (:attr:`.selection.OutOfSample.std_pct`). On the data it was adapted on it gives the std
    that a record written before ``std_pct_condition_out`` existed lacks; on other engines
    of the same engine type, how the adaptation holds there. ``model``: a prebuilt
    :class:`~calibration.discrepancy.candidates.CandidateModel` whose candidates include the
    record's chosen ones, e.g. the one the adaptation ran with (tests; its other candidates
    stay at 0, which leaves the engine as it is); ``design``: the engine design to build it on
    (:func:`engine_model.physics.design.design_engine`; default the model's own)."""
    from calibration.discrepancy.candidates import CandidateModel

    info = record.get("data", {})
    chosen = list(record["selection"]["chosen"])
    data, _ = fleet_data(df, tuple(record["channels"]),
                         info.get("early_cycles", EARLY_CYCLES), units, source=source,
                         model_error=info.get("model_error", 0.0),
                         shared_model_error=info.get("model_error_shared", False))
    check_fleet(data, source)
    if model is None:  # (record_groups refuses a name it does not know)
        groups = record_groups(record, data.channels)
    else:
        prebuilt_groups(model, chosen, "chosen candidate")
        groups = model.candidates
    value = {(p["candidate"], p["parameter"]): p["value"] for p in record["parameters"]}
    phi = np.zeros(sum(len(c.params) for c in groups))
    for c in groups:
        for j, q in enumerate(c.params):
            if c.name in chosen and (c.name, q) not in value:
                raise InputError(f"the adapted model: no value of {c.name}.{q}, a parameter "
                                 "of a chosen candidate")
            phi[c.index[j]] = value.get((c.name, q), 0.0)
    model = model or CandidateModel(groups, design=design, sens_outputs=data.channels)
    shared = shared_of(groups, chosen)
    fit = fit_fleet(model, data, shared, phi)
    return fit, condition_out(model, data, shared, fit)
