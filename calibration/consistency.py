"""The model's own error chosen so that the filter is consistent with the data.

A Kalman filter whose ``R`` and ``Q`` describe the data has normalised innovations
``nu_k^T S_k^-1 nu_k`` (NIS) distributed as chi-square with ``m`` degrees of freedom, ``m`` the
number of channels: their mean over a fleet, divided by ``m``, is 1 (Bar-Shalom, Li &
Kirubarajan, *Estimation with Applications to Tracking and Navigation*, 2001, sec. 5.4; the
"covariance matching" of Mehra, IEEE TAC 17, 1972). On measured data the model is not the
engine, and a filter told only of the sensor noise trusts the model too much: on C-MAPSS
(UKF, the paper's three parameters) the mean NIS per channel is 7.5 on FD001 and 554 on FD002
(``benchmarks/calibration_noise.py``).

:func:`consistent_model_error` finds the model error ``e`` (a relative std added to the noise
in quadrature, :func:`calibration.measurement_noise.with_model_error`) at which that mean is
1: the fleet is calibrated at trial values of ``e``, grown fourfold from ``1e-4`` until the
filter is consistent and then bisected in ``log e``, since the mean NIS falls as ``e`` grows
(each trial is a whole calibration: about 15 s for FD002's 17,000 samples on one core, a
search of about ten). When the filter is consistent without it, ``e = 0``.

What it cannot do: the model's mismatch on C-MAPSS is a bias per operating condition, not
white noise, so a consistent white ``R`` can be too large for the wear to show: with the model
as designed FD002 needs about 1.7 %, at which the HPT and LPT efficiencies stop following the
wear; adapted to the fleet (``hyprog adapt``) it needs about 0.7 % and theta_hat still follows
it (docs/calibration.md). The condition-dependent error belongs in the model; this is what is
left of it.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pandas as pd

from .estimation_setup import CalibrationSetup

#: The model errors searched (relative std): below the lower end the noise dominates, the
#: upper end is the largest :func:`~calibration.measurement_noise.check_model_error` allows.
SEARCH = (1e-4, 0.099)
#: Relative width of the final bracket on ``e``.
RTOL = 0.05


def fleet_nis(data, setup: CalibrationSetup, effects=(), units=None) -> float:
    """The mean NIS per channel over every converged sample of the fleet, calibrated with the
    UKF and ``setup`` (a fleet of units with different channel counts: each unit's mean NIS
    divided by its own count)."""
    from . import UnobservableWarning
    from .calibrate_fleet import calibrate_fleet

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnobservableWarning)
        run = calibrate_fleet(data, "ukf", setup, units=units, check_data=False,
                              effects=effects)
    total = count = 0.0
    for r in run.results.values():
        d = r.diagnostics
        n = d["n_samples"] - d["n_nonconverged"]
        if n > 0 and np.isfinite(d["nis_mean"]):
            total += n * d["nis_mean"] / d["nis_dof"]
            count += n
    return total / count if count else float("nan")


def consistent_model_error(data, setup: CalibrationSetup, effects=(), units=None,
                           log=None) -> tuple[float, float]:
    """``(e, NIS per channel at e)``: the model error at which the fleet's mean NIS per
    channel is 1 (module docstring), within :data:`RTOL`; 0 when the filter is consistent
    without one, the upper end of :data:`SEARCH` when even that is not enough. From the
    lower end of :data:`SEARCH` the trial grows fourfold until the filter is consistent,
    then ``log e`` is bisected. A trial at which every parameter is unobservable (the model
    error drowns the data) counts as consistent: the answer lies below it."""
    from engine_model.validation import InputError

    def nis(e: float) -> float:
        try:
            v = fleet_nis(data, replace(setup, model_error=e), effects, units)
        except InputError:
            if e == 0.0:
                raise
            v = 0.0  # nothing observable: far on the consistent side
        if log:
            log(f"model error {e:.4g}: mean NIS per channel {v:.3g}")
        return v

    at0 = nis(0.0)
    if at0 <= 1.0:
        return 0.0, at0
    lo, (e, top) = None, SEARCH
    while True:
        v = nis(e)
        if v <= 1.0:
            hi, v_hi = e, v
            break
        if e >= top:
            return e, v
        lo, e = e, min(4.0 * e, top)
    if lo is None:
        return hi, v_hi
    while hi / lo > 1.0 + RTOL:
        mid = float(np.sqrt(lo * hi))
        v = nis(mid)
        if v > 1.0:
            lo = mid
        else:
            hi, v_hi = mid, v
    return hi, v_hi  # the smallest tried at which the filter is consistent


def with_consistent_model_error(setup: CalibrationSetup, data, effects=(), units=None,
                                log=None) -> tuple[CalibrationSetup, float]:
    """``(setup with the consistent model error, NIS per channel there)``: the data's noise
    table first when ``setup.noise == "data"`` (every trial uses the same), then
    :func:`consistent_model_error` (``hyprog calibrate --model-error consistent`` and the
    pipeline's ``model_error = "consistent"``)."""
    from .calibrate_fleet import with_data_noise

    if setup.noise == "data" and not setup.noise_table:
        setup = with_data_noise(setup, data, None if isinstance(data, pd.DataFrame)
                                else str(data))
    e, nis = consistent_model_error(data, setup, effects, units, log)
    return replace(setup, model_error=e), nis


def with_measured_noise(setup: CalibrationSetup, data, effects=(), units=None,
                        consistent: bool = False, log=None) -> CalibrationSetup:
    """The setup's R resolved for ``data`` as ``hyprog calibrate`` and ``hyprog discover``
    resolve it: with ``consistent`` the consistent model error
    (:func:`with_consistent_model_error`, the data's noise table first when ``noise ==
    "data"``), else the data's noise table when ``noise == "data"``, else ``setup``."""
    from .calibrate_fleet import with_data_noise

    if consistent:
        return with_consistent_model_error(setup, data, effects, units, log)[0]
    if setup.noise == "data" and not setup.noise_table:
        return with_data_noise(setup, data, None if isinstance(data, pd.DataFrame)
                               else str(data))
    return setup
