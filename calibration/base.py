"""One interface for every estimator of the health parameters ``theta``.

An estimator takes one unit's time series (a DataFrame with the N-CMAPSS names: ``w`` columns
``alt Mach TRA T2``, the measured channels it uses, optionally ``t`` and ``cycle``) and a
:class:`CalibrationSetup`, and returns a :class:`CalibrationResult`: ``theta_hat(t)``, its
standard deviation and covariance, ``x_hat`` for every measured and virtual channel,
normalised residuals and diagnostics. Estimators are looked up by name in :data:`ESTIMATORS`
(``ukf``, ``ekf``, ``mhe``, ``map_cycle``) through :func:`get_estimator`.

State-space model shared by all (paper eq. 5-6)::

    theta_k = theta_{k-1} + xi_k,        xi_k  ~ N(0, Q_k),   Q_k = q^2 dtau_k I
    y_k     = F(w_k, theta_k) + eps_k,   eps_k ~ N(0, R_k),   R_k = diag(s sigma_rel |y_k|)^2

- ``F`` is the exact steady-state engine model (:class:`engine_model.EngineModel`), ``y`` the
  chosen measured channels.
- ``R_k``: the sensor noise of :mod:`engine_model.sensor_noise` (proportional to the reading;
  ``s = noise_scale``), evaluated at the measured reading (the difference to the noise-free
  reading is a fraction of a percent of sigma).
- ``Q_k``: a random walk in **operating time**, ``dtau_k`` [h] of operation before sample
  ``k``; ``q = drift_std_per_sqrt_h``. Where the drift goes (``drift_per``):

  * ``"cycle"`` (default when the data have a ``cycle`` column): theta is constant within a
    flight and the wear of a whole flight enters at the first sample of the next cycle,
    ``dtau`` = the recorded duration of the previous cycle (0 within a cycle). This is how
    N-CMAPSS and our simulator define theta (one value per cycle), so it is the exact prior.
  * ``"time"`` (default without ``cycle``): continuous wear, ``dtau`` = the time since the
    previous sample of the same flight (``t`` column); one sample period across a flight
    boundary or without ``t``.

  Default ``q`` = 1e-3 per sqrt(hour). In the ``ds02`` preset the abnormal HPT wear is
  steepest just before end of life, about 0.05-0.1 % of efficiency per flight of 2-5 h
  (:mod:`engine_model.degradation`: about 3 % lost over 50-70 cycles along
  ``exp(u) - 1 - u``), i.e. below 1 ``q sqrt(flight hours)``; normal wear (1e-4 per cycle) is
  far inside it. Data that degrade faster (the ``tiny`` preset: 10-cycle lives) need a
  larger ``q``.
- Prior at the first sample ``N(prior_mean, prior_std^2)``; default mean 0 (new engine), std
  0.02 (ten times the simulator's initial wear, so the prior is weak but keeps an unobservable
  direction bounded). Non-estimated parameters are held at ``theta_fixed`` (default 0).

Observability (:func:`check_observability`, used by every estimator before it estimates). The
Fisher information of the chosen sensors about the chosen parameters over the unit (exact
sensitivities ``S_k = R_k^{-1/2} dF/dtheta`` at the prior mean, up to
``observability_samples`` samples spread over the unit, scaled to the unit's length)::

    I = sum_k S_k^T S_k

While ``I`` is rank-deficient (smallest eigenvalue below ``observability_rtol`` times the
largest) or a parameter's data-only standard deviation ``sqrt((I^-1)_jj)`` exceeds
``observability_max_std`` (default 0.02, the default prior std: data that pin a parameter down
less well than the prior already does say nothing useful about it; e.g. ``Nf`` and ``P2``
alone, which the fan-speed control and the inlet fix, give HPT_eff_mod a data-only std of
about 0.1 over two flights), the
parameter with the largest weight in the weakest direction (or the largest std) is declared
**unobservable**. Policy ``setup.unobservable``: ``"exclude"`` (default) holds it at its prior
mean, reports NaN for its estimate and standard deviation, lists it in
``diagnostics["unobservable"]`` and issues an :class:`UnobservableWarning`; ``"raise"`` raises
:class:`UnobservableError` instead. It is never silently estimated.
"""

from __future__ import annotations

import importlib
import time
import warnings
from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd

from engine_model.channels import PAPER_THETA, THETA_NAMES, W_NAMES, XS_NAMES, XV_NAMES
from engine_model.sensor_noise import sigma_abs
from engine_model.validation import ENVELOPE, InputError

N_THETA = len(THETA_NAMES)
HAT_NAMES = tuple(c + "_hat" for c in XS_NAMES + XV_NAMES)

DEFAULT_DRIFT_STD_PER_SQRT_H = 1e-3
DEFAULT_PRIOR_STD = 0.02
DEFAULT_SAMPLE_PERIOD_S = 10.0  # 0.1 Hz, used only when the data have no ``t`` column


class UnobservableError(InputError):
    """The chosen sensors cannot determine one of the chosen health parameters."""


class UnobservableWarning(UserWarning):
    """A requested health parameter was not estimated because it is unobservable."""


# ----------------------------------------------------------------------------- setup
def _vec(value, n, what) -> np.ndarray:
    a = np.asarray(value, float)
    if a.ndim == 0:
        return np.full(n, float(a))
    if a.shape != (n,):
        raise InputError(f"{what}: expected one value or {n} values, got {a.size}")
    return a.copy()


@dataclass(frozen=True)
class CalibrationSetup:
    """What to estimate from which channels, and the noise model (defaults in brackets).

    ``params``      health parameters to estimate [the paper's HPT_eff_mod, LPT_eff_mod,
                    LPT_flow_mod]; any subset of :data:`channels.THETA_NAMES`
    ``sensors``     measured channels to use [None: every x_s channel present in the data]
    ``noise_scale`` multiplier of the documented sensor noise in ``R`` [1]
    ``drift_std_per_sqrt_h``  random-walk std of theta per sqrt(hour of operation) [1e-3]
    ``prior_mean``  prior mean of the estimated theta at the first sample, one value or one
                    per parameter [0]
    ``prior_std``   prior std, one value or one per parameter [0.02]
    ``theta_fixed`` values of the non-estimated theta (name -> value) [all 0]
    ``bounds``      box on every estimated theta [the model's envelope, (-0.15, 0.05)]
    ``sample_period_s`` sample period when the data have no ``t`` column [10 s]
    ``drift_per``   ``"cycle"``, ``"time"`` or ``"auto"`` (module docstring) ["auto"]
    ``unobservable`` ``"exclude"`` or ``"raise"`` (module docstring) ["exclude"]
    ``observability_rtol`` / ``observability_max_std`` / ``observability_samples``
                    the rank test of the Fisher information [1e-8 / 0.02 / 400]
    """

    params: tuple = PAPER_THETA
    sensors: tuple | None = None
    noise_scale: float = 1.0
    drift_std_per_sqrt_h: float = DEFAULT_DRIFT_STD_PER_SQRT_H
    prior_mean: float | tuple = 0.0
    prior_std: float | tuple = DEFAULT_PRIOR_STD
    theta_fixed: tuple = ()
    bounds: tuple = ENVELOPE.theta
    sample_period_s: float = DEFAULT_SAMPLE_PERIOD_S
    drift_per: str = "auto"
    unobservable: str = "exclude"
    observability_rtol: float = 1e-8
    observability_max_std: float = DEFAULT_PRIOR_STD
    observability_samples: int = 400

    def __post_init__(self):
        params = (self.params,) if isinstance(self.params, str) else tuple(self.params)
        object.__setattr__(self, "params", params)
        if not params:
            raise InputError("calibration: no health parameter to estimate")
        bad = [q for q in params if q not in THETA_NAMES]
        if bad:
            raise InputError(f"unknown health parameter(s) {', '.join(bad)}; one of "
                             f"{', '.join(THETA_NAMES)}")
        if len(set(params)) != len(params):
            raise InputError(f"health parameters listed twice: {', '.join(params)}")
        if self.sensors is not None:
            sensors = (self.sensors,) if isinstance(self.sensors, str) else tuple(self.sensors)
            object.__setattr__(self, "sensors", sensors)
            bad = [c for c in sensors if c not in XS_NAMES]
            if bad:
                raise InputError(f"unknown sensor(s) {', '.join(bad)}; measured channels are "
                                 f"{', '.join(XS_NAMES)}")
            if not sensors:
                raise InputError("calibration: no sensor to use")
        fixed = self.theta_fixed
        if isinstance(fixed, Mapping):
            fixed = tuple(sorted(fixed.items()))
        fixed = tuple((str(k), float(v)) for k, v in fixed)
        bad = [k for k, _ in fixed if k not in THETA_NAMES]
        if bad:
            raise InputError(f"theta_fixed: unknown health parameter(s) {', '.join(bad)}")
        object.__setattr__(self, "theta_fixed", fixed)
        for name in ("prior_mean", "prior_std"):
            v = getattr(self, name)
            if np.ndim(v):
                object.__setattr__(self, name, tuple(float(x) for x in np.ravel(v)))
        _vec(self.prior_mean, len(params), "prior_mean")
        if np.any(_vec(self.prior_std, len(params), "prior_std") <= 0):
            raise InputError("prior_std must be positive")
        if not (self.noise_scale > 0):
            raise InputError(f"noise_scale must be positive, got {self.noise_scale}")
        if not (self.drift_std_per_sqrt_h >= 0):
            raise InputError("drift_std_per_sqrt_h must be >= 0")
        lo, hi = self.bounds
        if not lo < hi:
            raise InputError(f"bounds: lower {lo} must be below upper {hi}")
        if self.drift_per not in ("auto", "cycle", "time"):
            raise InputError(f"drift_per must be 'auto', 'cycle' or 'time', "
                             f"got {self.drift_per!r}")
        if self.unobservable not in ("exclude", "raise"):
            raise InputError(f"unobservable policy must be 'exclude' or 'raise', "
                             f"got {self.unobservable!r}")

    # -- derived quantities
    @property
    def k(self) -> int:
        return len(self.params)

    @property
    def param_index(self) -> np.ndarray:
        """Positions of ``params`` in :data:`THETA_NAMES`."""
        return np.array([THETA_NAMES.index(q) for q in self.params], int)

    def prior_mean_vec(self) -> np.ndarray:
        return _vec(self.prior_mean, self.k, "prior_mean")

    def prior_std_vec(self) -> np.ndarray:
        return _vec(self.prior_std, self.k, "prior_std")

    def theta_base(self) -> np.ndarray:
        """The full (10,) theta with the fixed values and the prior mean of the estimated."""
        th = np.zeros(N_THETA)
        for k, v in self.theta_fixed:
            th[THETA_NAMES.index(k)] = v
        th[self.param_index] = self.prior_mean_vec()
        return th

    def full_theta(self, theta_est: np.ndarray) -> np.ndarray:
        """(..., k) estimated values -> (..., 10) full theta."""
        theta_est = np.asarray(theta_est, float)
        th = np.broadcast_to(self.theta_base(), (*theta_est.shape[:-1], N_THETA)).copy()
        th[..., self.param_index] = theta_est
        return th

    def resolve_sensors(self, columns) -> tuple:
        """The sensors to use for data with ``columns``: the requested ones (each must be
        present) or every measured channel present."""
        if self.sensors is None:
            sensors = tuple(c for c in XS_NAMES if c in columns)
            if not sensors:
                raise InputError(f"data: none of the measured channels {', '.join(XS_NAMES)}"
                                 " is present")
            return sensors
        absent = [c for c in self.sensors if c not in columns]
        if absent:
            raise InputError(f"missing sensor column(s) {', '.join(absent)}")
        return self.sensors

    def with_params(self, params) -> CalibrationSetup:
        """The same setup for a subset of its parameters (prior values carried over)."""
        params = tuple(params)
        pm, ps = self.prior_mean_vec(), self.prior_std_vec()
        sel = [self.params.index(q) for q in params]
        return replace(self, params=params, prior_mean=tuple(pm[sel]), prior_std=tuple(ps[sel]))


# ----------------------------------------------------------------------------- data
@dataclass
class UnitSeries:
    """One unit's data as arrays, checked.

    ``w`` (N, 4), ``y`` (N, m) readings of ``sensors``, ``sigma`` (N, m) their noise std,
    ``dt_h`` (N,) operating time since the previous sample [h] (0 at the first; one sample
    period across a flight boundary), ``dtau_h`` (N,) the drift time before each sample
    (``setup.drift_per``: equal to ``dt_h``, or the previous cycle's duration at a cycle's
    first sample and 0 elsewhere),
    ``cycle`` (N,) or None, ``index`` the input rows' labels, ``unit`` the unit label or None.
    """

    w: np.ndarray
    y: np.ndarray
    sigma: np.ndarray
    dt_h: np.ndarray
    dtau_h: np.ndarray
    sensors: tuple
    index: pd.Index
    cycle: np.ndarray | None = None
    unit: object = None

    def __len__(self):
        return len(self.w)

    def q_diag(self, setup: CalibrationSetup) -> np.ndarray:
        """(N,) variance of the random-walk step before each sample (same for every theta)."""
        return setup.drift_std_per_sqrt_h ** 2 * self.dtau_h


def _where(unit, source) -> str:
    parts = [str(source)] if source is not None else []
    if unit is not None:
        parts.append(f"unit {unit}")
    return (", ".join(parts) + ": ") if parts else ""


def prepare_unit(df: pd.DataFrame, setup: CalibrationSetup, source=None) -> UnitSeries:
    """Check and convert one unit's DataFrame. Errors name the source (file), unit, row and
    column: a missing column, a NaN or infinite value, an operating point outside the
    envelope, a reading <= 0 where the noise model needs a positive one."""
    unit = None
    if "unit" in df.columns and len(df):
        u = pd.unique(df["unit"])
        if len(u) > 1:
            raise InputError(f"{_where(None, source)}one unit at a time, got units "
                             f"{', '.join(map(str, u[:5]))}")
        unit = u[0].item() if hasattr(u[0], "item") else u[0]
    where = _where(unit, source)
    if len(df) == 0:
        raise InputError(f"{where}no rows")
    missing = [c for c in W_NAMES if c not in df.columns]
    if missing:
        raise InputError(f"{where}missing column(s) {', '.join(missing)}")
    try:
        sensors = setup.resolve_sensors(df.columns)
    except InputError as e:
        raise InputError(f"{where}{e}") from None
    index = df.index
    w = df[list(W_NAMES)].to_numpy(float)
    y = df[list(sensors)].to_numpy(float)
    for arr, names in ((w, W_NAMES), (y, sensors)):
        bad = ~np.isfinite(arr)
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise InputError(f"{where}row {index[i]}, column {names[j]}: value is {arr[i, j]}"
                             " (NaN or infinite)")
    nonpos = y <= 0
    if nonpos.any():
        i, j = np.argwhere(nonpos)[0]
        raise InputError(f"{where}row {index[i]}, column {sensors[j]} = {y[i, j]:g}: a "
                         "reading must be positive (noise is proportional to it)")
    from engine_model.validation import check_w

    try:
        check_w(w, np.asarray(index), "data")
    except InputError as e:
        raise InputError(f"{where}{str(e).removeprefix('data: ')}") from None
    sigma = sigma_abs(y, sensors, scale=setup.noise_scale)
    n = len(df)
    cycle = df["cycle"].to_numpy() if "cycle" in df.columns else None
    period = setup.sample_period_s
    if "t" in df.columns:
        t = df["t"].to_numpy(float)
        if not np.all(np.isfinite(t)):
            i = int(np.flatnonzero(~np.isfinite(t))[0])
            raise InputError(f"{where}row {index[i]}, column t: value is {t[i]}")
        dt = np.diff(t, prepend=t[0])
        pos = dt[dt > 0]
        period = float(np.median(pos)) if pos.size else period
        new = dt <= 0
        if cycle is not None:
            new |= np.diff(cycle, prepend=cycle[0]) != 0
        dt = np.where(new, period, dt)
    else:
        dt = np.full(n, period)
    dt[0] = 0.0
    per = setup.drift_per
    if per == "auto":
        per = "cycle" if cycle is not None else "time"
    if per == "cycle":
        if cycle is None:
            raise InputError(f"{where}drift per cycle needs a 'cycle' column")
        starts = np.flatnonzero(np.diff(cycle, prepend=cycle[0]) != 0)
        # a cycle's recorded duration: the spacing of its samples, one period for the first
        durations = np.add.reduceat(dt, np.concatenate([[0], starts]))
        durations[0] += period
        dtau = np.zeros(n)
        dtau[starts] = durations[:-1]
    else:
        dtau = dt.copy()
    return UnitSeries(w=w, y=y, sigma=sigma, dt_h=dt / 3600.0, dtau_h=dtau / 3600.0,
                      sensors=sensors, index=index, cycle=cycle, unit=unit)


# ----------------------------------------------------------------------------- Fisher / rank
def scaled_sensitivities(model, w, x, theta_full, sigma, sensors, params_idx, p=None):
    """``S = diag(1/sigma) dy/dtheta`` (N, m, k) for ``sensors`` and the theta at ``params_idx``
    at the converged unknowns ``x``, exact (implicit function theorem, CasADi)."""
    from engine_model.channels import OUTPUT_NAMES

    dth, _ = model.sensitivities(np.asarray(w, float), np.asarray(theta_full, float), p=p, x=x)
    rows = [OUTPUT_NAMES.index(c) for c in sensors]
    J = dth[:, rows][:, :, params_idx]
    return J / sigma[:, :, None]


def fisher_information(S: np.ndarray) -> np.ndarray:
    """``sum_k S_k^T S_k`` of scaled sensitivities (N, m, k) -> (k, k)."""
    return np.einsum("nmi,nmj->ij", S, S)


def observability_split(info: np.ndarray, rtol: float = 1e-8,
                        max_std: float = DEFAULT_PRIOR_STD):
    """Greedy rank test of a Fisher information (module docstring). Returns ``(keep,
    dropped, rank)``: indices into its rows of the observable and unobservable parameters and
    the numerical rank of ``info``."""
    info = 0.5 * (np.asarray(info, float) + np.asarray(info, float).T)
    lam_all = np.linalg.eigvalsh(info)
    lmax_all = max(float(lam_all[-1]), 0.0)
    rank = int(np.sum(lam_all > rtol * lmax_all)) if lmax_all > 0 else 0
    keep = list(range(len(info)))
    dropped = []
    while keep:
        sub = info[np.ix_(keep, keep)]
        lam, vec = np.linalg.eigh(sub)
        lmax = float(lam[-1])
        if lmax <= 0 or lam[0] < rtol * lmax:
            j = int(np.argmax(np.abs(vec[:, 0])))
        else:
            std = np.sqrt(np.clip(np.diag(np.linalg.inv(sub)), 0, None))
            if std.max() <= max_std:
                break
            j = int(np.argmax(std))
        dropped.append(keep.pop(j))
    return keep, sorted(dropped), rank


@dataclass
class Observability:
    """Result of :func:`check_observability`."""

    observable: tuple  # parameter names
    unobservable: tuple
    fisher: np.ndarray  # (k, k) over the whole unit, all requested parameters
    rank: int
    data_std: dict  # parameter -> sqrt((I^-1)_jj) of the observable block


def check_observability(model, series: UnitSeries, setup: CalibrationSetup, x=None, p=None,
                        apply_policy: bool = True) -> Observability:
    """Fisher information of ``setup.sensors`` about ``setup.params`` over the unit at the
    prior mean, its rank, and which parameters are unobservable. With ``apply_policy``,
    ``setup.unobservable == "raise"`` raises :class:`UnobservableError` and ``"exclude"``
    warns (:class:`UnobservableWarning`)."""
    n = len(series)
    idx = np.unique(np.linspace(0, n - 1, min(n, setup.observability_samples)).astype(int))
    w = series.w[idx]
    th = np.tile(setup.theta_base(), (len(idx), 1))
    pm = None if p is None else np.asarray(p)[idx] if np.ndim(p) == 2 else p
    if x is None:
        r = model.solve_series(w, th, pm)
        ok = r.converged
        if not ok.any():
            raise InputError(f"{_where(series.unit, None)}steady state did not converge at "
                             "the prior mean anywhere; cannot check observability")
        xs, w, th, sig = r.x[ok], w[ok], th[ok], series.sigma[idx][ok]
        pm = pm[ok] if pm is not None and np.ndim(pm) == 2 else pm
    else:
        xs, sig = np.asarray(x)[idx], series.sigma[idx]
    S = scaled_sensitivities(model, w, xs, th, sig, series.sensors, setup.param_index, pm)
    info = fisher_information(S) * (n / len(xs))
    keep, dropped, rank = observability_split(info, setup.observability_rtol,
                                              setup.observability_max_std)
    sub = info[np.ix_(keep, keep)]
    std = np.sqrt(np.diag(np.linalg.inv(sub))) if keep else np.array([])
    obs = Observability(observable=tuple(setup.params[i] for i in keep),
                        unobservable=tuple(setup.params[i] for i in dropped),
                        fisher=info, rank=rank,
                        data_std={setup.params[i]: float(s) for i, s in zip(keep, std,
                                                                            strict=True)})
    if apply_policy and obs.unobservable:
        msg = (f"{_where(series.unit, None)}health parameter(s) {', '.join(obs.unobservable)}"
               f" cannot be observed with sensors {', '.join(series.sensors)} (Fisher "
               f"information rank {rank} of {setup.k}; a parameter also counts as "
               f"unobservable when the data pin it down less than the prior std "
               f"{setup.observability_max_std:g} does)")
        if setup.unobservable == "raise" or not obs.observable:
            raise UnobservableError(msg)
        warnings.warn(msg + "; held at the prior mean, reported as NaN",
                      UnobservableWarning, stacklevel=2)
    return obs


# ----------------------------------------------------------------------------- result
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
    from engine_model.channels import OUTPUT_NAMES

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


# ----------------------------------------------------------------------------- estimators
_MODELS: dict = {}


def default_model(compiled: bool = True):
    """One :class:`engine_model.EngineModel` per process (no optional effects)."""
    if compiled not in _MODELS:
        from engine_model import EngineModel

        _MODELS[compiled] = EngineModel(compiled=compiled)
    return _MODELS[compiled]


class Estimator(ABC):
    """Base class of the estimators. ``estimate`` runs one unit; ``estimate_many`` runs a
    list of units (default: one after the other; the filters run them in lockstep).

    Subclasses set ``name`` and take the engine model (default :func:`default_model`) and
    their own options as keyword arguments of ``__init__``.
    """

    name: str = "?"

    def __init__(self, model=None):
        self.model = model if model is not None else default_model()

    @abstractmethod
    def estimate(self, df_unit: pd.DataFrame, setup: CalibrationSetup | None = None,
                 source=None) -> CalibrationResult:
        """Estimate ``setup.params`` along one unit's series (``source`` names the file in
        error messages)."""

    def estimate_many(self, units: Sequence[pd.DataFrame],
                      setup: CalibrationSetup | None = None,
                      source=None) -> list[CalibrationResult]:
        return [self.estimate(df, setup, source) for df in units]


def timed(diag: dict, t0: float, n: int) -> dict:
    """Add ``seconds`` and ``samples_per_second`` to a diagnostics dict."""
    dt = time.perf_counter() - t0
    diag["seconds"] = dt
    diag["samples_per_second"] = n / dt if dt > 0 else float("inf")
    return diag


# name -> "module:attribute"; modules are imported when first asked for, so that e.g. the
# filters work where IPOPT's MHE module is absent.
ESTIMATORS: dict[str, str] = {
    "ukf": "calibration.ukf:UKF",
    "ekf": "calibration.ekf:EKF",
    "mhe": "calibration.mhe:MHEEstimator",
    "map_cycle": "calibration.mhe:MAPCycleEstimator",
}


def estimator_class(name: str) -> Callable[..., Estimator]:
    """The estimator class registered as ``name`` (clear error when unknown or absent)."""
    if name not in ESTIMATORS:
        raise InputError(f"unknown calibration method {name!r}; one of "
                         f"{', '.join(ESTIMATORS)}")
    mod_name, attr = ESTIMATORS[name].split(":")
    try:
        mod = importlib.import_module(mod_name)
    except ModuleNotFoundError as e:
        if e.name != mod_name:
            raise
        raise InputError(f"calibration method {name!r} is not available: module {mod_name} "
                         "is missing") from None
    cls = getattr(mod, attr, None)
    if cls is None:
        raise InputError(f"calibration method {name!r} is not available: {mod_name} has no "
                         f"{attr}")
    return cls


def get_estimator(name: str, model=None, **options) -> Estimator:
    """An estimator instance by registered name, e.g. ``get_estimator("ukf")``."""
    return estimator_class(name)(model=model, **options)
