"""What every estimator returns: :class:`CalibrationResult`, and the feature table of the
paper (inputs, ``x_hat`` of every x_s and x_v channel, ``theta_hat`` and its std)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from engine_model.channels import OUTPUT_NAMES, XS_NAMES, XV_NAMES
from engine_model.validation import InputError

from .estimation_setup import CalibrationSetup
from .series import UnitSeries

HAT_NAMES = tuple(c + "_hat" for c in XS_NAMES + XV_NAMES)


@dataclass
class CalibrationResult:
    """Per-sample estimates of one unit (index = the input rows).

    ``theta_hat``  DataFrame ``<theta>_hat`` for every requested parameter (NaN if unobservable)
    ``theta_std``  DataFrame ``<theta>_hat_std``
    ``theta_cov``  (N, k, k) posterior covariance of the requested parameters (NaN rows and
                   columns for unobservable ones)
    ``x_hat``      DataFrame ``<c>_hat`` for every x_s and x_v channel at ``theta_hat``
    ``residuals``  DataFrame of normalised residuals ``(y - y_hat) / sigma`` for the used
                   sensors (columns named after the sensors), before the update for a filter
                   (innovations) unless stated in ``diagnostics["residuals"]``
    ``diagnostics`` dict: method, params, sensors, unobservable, fisher_rank, iterations,
                   n_nonconverged, seconds, samples_per_second, and method-specific entries
    """

    params: tuple
    sensors: tuple
    theta_hat: pd.DataFrame
    theta_std: pd.DataFrame
    theta_cov: np.ndarray
    x_hat: pd.DataFrame
    residuals: pd.DataFrame
    diagnostics: dict = field(default_factory=dict)

    @property
    def unobservable(self) -> tuple:
        return tuple(self.diagnostics.get("unobservable", ()))

    def to_features(self, df_in: pd.DataFrame) -> pd.DataFrame:
        """The paper's feature table: the input columns, then ``<x>_hat`` for every x_s and
        x_v channel, ``<theta>_hat`` and ``<theta>_hat_std`` for each estimated parameter."""
        if len(df_in) != len(self.theta_hat):
            raise InputError(f"features: {len(df_in)} input rows but {len(self.theta_hat)} "
                             "estimates")
        parts = [df_in.reset_index(drop=True)]
        for extra in (self.x_hat, self.theta_hat, self.theta_std):
            parts.append(extra.reset_index(drop=True))
        out = pd.concat(parts, axis=1)
        out.index = df_in.index
        return out


def make_result(series: UnitSeries, setup: CalibrationSetup, theta_hat: np.ndarray,
                theta_cov: np.ndarray, y_hat_all: np.ndarray, residuals: np.ndarray,
                diagnostics: dict, unobservable: Sequence[str] = ()) -> CalibrationResult:
    """Assemble a :class:`CalibrationResult` from arrays: ``theta_hat`` (N, k) and
    ``theta_cov`` (N, k, k) of ``setup.params`` (entries of unobservable parameters are set to
    NaN here), ``y_hat_all`` (N, len(OUTPUT_NAMES)) model outputs, ``residuals`` (N, m)."""
    theta_hat = np.array(theta_hat, float)
    theta_cov = np.array(theta_cov, float)
    for q in unobservable:
        j = setup.params.index(q)
        theta_hat[:, j] = np.nan
        theta_cov[:, j, :] = np.nan
        theta_cov[:, :, j] = np.nan
    std = np.sqrt(np.clip(np.diagonal(theta_cov, axis1=1, axis2=2), 0, None))
    idx = series.index
    cols = [OUTPUT_NAMES.index(c) for c in XS_NAMES + XV_NAMES]
    diag = dict(diagnostics)
    diag.setdefault("params", list(setup.params))
    diag["sensors"] = list(series.sensors)
    diag["unobservable"] = list(unobservable)
    return CalibrationResult(
        params=setup.params, sensors=series.sensors,
        theta_hat=pd.DataFrame(theta_hat, index=idx, columns=[q + "_hat" for q in setup.params]),
        theta_std=pd.DataFrame(std, index=idx, columns=[q + "_hat_std" for q in setup.params]),
        theta_cov=theta_cov,
        x_hat=pd.DataFrame(np.asarray(y_hat_all)[:, cols], index=idx, columns=list(HAT_NAMES)),
        residuals=pd.DataFrame(residuals, index=idx, columns=list(series.sensors)),
        diagnostics=diag)
