"""What to estimate, from which channels, under which noise and drift model.

State-space model shared by all (paper eq. 5-6)::

    theta_k = theta_{k-1} + xi_k,        xi_k  ~ N(0, Q_k),   Q_k = q^2 dtau_k I
    y_k     = F(w_k, theta_k) + eps_k,   eps_k ~ N(0, R_k),   R_k = diag(s sigma_rel |y_k|)^2

- ``F`` is the exact steady-state model (:class:`engine_model.EngineModel`, or any
  :class:`engine_model.solver.interface.SteadyStateModel`), ``y`` the chosen measured channels
  (with ``noise="data"`` also other model outputs the data record: :data:`DERIVED_SENSORS`).
- ``R_k``: the sensor noise of :mod:`engine_model.simulator.sensor_noise` (proportional to
  the reading; ``s = noise_scale``), evaluated at the measured reading (the difference to the
  noise-free reading is a fraction of a percent of sigma). That table is hyprog's simulator's
  noise, set from C-MAPSS's scatter; on measured data the data's own noise is better known
  than assumed: with ``noise="data"`` ``R_k = diag(s sigma_j,c(k))^2``, each channel's std at
  the sample's operating condition ``c(k)`` estimated from the calibrated data themselves,
  within units, early in life (:func:`calibration.measurement_noise.noise_from_data`; the data
  need a ``condition`` label, as a C-MAPSS import has). On C-MAPSS FD001 that estimate is
  2.4x the simulator's for T24, 1.7x for T30 and 2.2x for Ps30, but 7.5x smaller for P15
  (written to 0.01 psia, its rounding alone) and 4x smaller for Nf. ``model_error`` (a
  relative std, default 0) adds the model's own error in quadrature, ``(model_error y_k)^2``
  (Kennedy & O'Hagan 2001; :func:`calibration.measurement_noise.with_model_error`), so that a
  channel written almost without noise does not rule the estimate with the model's
  mismatch.
- ``Q_k``: a random walk in **operating time**, ``dtau_k`` [h] of operation before sample
  ``k``; ``q = drift``. Where the drift goes (``drift_per``):

  * ``"cycle"`` (default when the data have a ``cycle`` column): theta is constant within a
    flight and the wear of a whole flight enters at the first sample of the next cycle,
    ``dtau`` = the recorded duration of the previous cycle (0 within a cycle). This is how
    N-CMAPSS and our simulator define theta (one value per cycle), so it is the exact prior.
  * ``"time"`` (default without ``cycle``): continuous wear, ``dtau`` = the time since the
    previous sample of the same flight (``t`` column); one sample period across a flight
    boundary or without ``t``.

  Default ``q`` = 1e-3 per sqrt(hour). In the ``ds02`` preset the abnormal HPT wear is
  steepest just before end of life, about 0.05-0.1 % of efficiency per flight of 2-5 h
  (:mod:`engine_model.simulator.degradation`: about 3 % lost over 50-70 cycles along
  ``exp(u) - 1 - u``), i.e. below 1 ``q sqrt(flight hours)``; normal wear (1e-4 per cycle) is
  far inside it. Data that degrade faster (the ``tiny`` preset: 10-cycle lives) need a
  larger ``q``.
- Prior at the first sample ``N(prior_mean, prior_std^2)``; default mean 0 (new engine), std
  0.02 (ten times the simulator's initial wear, so the prior is weak but keeps an unobservable
  direction bounded). Non-estimated parameters are held at ``theta_fixed`` (default 0).
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from dataclasses import dataclass, replace

import numpy as np

from engine_model.channels import (
    OUTPUT_NAMES,
    PAPER_THETA,
    THETA_NAMES,
    W_NAMES,
    XS_NAMES,
    XV_NAMES,
)
from engine_model.validation import ENVELOPE, InputError

from .measurement_noise import check_model_error

N_THETA = len(THETA_NAMES)

DEFAULT_DRIFT_STD_PER_SQRT_H = 1e-3
DEFAULT_PRIOR_STD = 0.02
DEFAULT_SAMPLE_PERIOD_S = 10.0  # 0.1 Hz, used only when the data have no ``t`` column


def _vec(value, n, what) -> np.ndarray:
    a = np.asarray(value, float)
    if a.ndim == 0:
        return np.full(n, float(a))
    if a.shape != (n,):
        raise InputError(f"{what}: expected one value or {n} values, got {a.size}")
    return a.copy()


#: model outputs besides the measured channels ``x_s`` that a data set may record as
#: readings, usable as sensors with the data's noise (``noise="data"``): C-MAPSS publishes
#: the bypass ratio ``BPR`` and the HPT / LPT coolant flows ``W31`` / ``W32`` (Saxena et al.
#: 2008, Table 2), flows that the gas-path temperatures and pressures alone do not pin
#: (docs/calibration.md, "Flow channels")
DERIVED_SENSORS = tuple(c for c in OUTPUT_NAMES if c not in XS_NAMES)

KNOWN_COLUMNS = frozenset(("unit", "cycle", "t", "Fc", "hs", "RUL", "phi", *W_NAMES, *XS_NAMES,
                           *XV_NAMES, *THETA_NAMES))


def misspelt_channels(columns) -> list[tuple[str, str]]:
    """``[(column, channel)]`` for each column that is not a known name but looks like a
    measured channel that is absent: the same name in another case, or one character away
    (``difflib`` ratio >= 0.6 with the same length), e.g. ``T3O`` -> ``T30``."""
    cols = [str(c) for c in columns]
    absent = [x for x in XS_NAMES if x not in cols]
    out = []
    for c in cols:
        if c in KNOWN_COLUMNS or c.endswith(("_hat", "_std")):
            continue
        same_case = [x for x in absent if x.lower() == c.strip().lower()]
        near = same_case or [x for x in difflib.get_close_matches(c, absent, n=1, cutoff=0.6)
                             if len(x) == len(c)]
        if near:
            out.append((c, near[0]))
    return out


@dataclass(frozen=True)
class CalibrationSetup:
    """What to estimate from which channels, and the noise model (defaults in brackets).

    ``params``      health parameters to estimate [the paper's HPT_eff_mod, LPT_eff_mod,
                    LPT_flow_mod]; any subset of :data:`channels.THETA_NAMES`
    ``sensors``     measured channels to use [None: every x_s channel present in the data
                    except ``exclude_sensors``]; with ``noise="data"`` also any other
                    output of the model the data record (:data:`DERIVED_SENSORS`, e.g.
                    C-MAPSS's ``BPR``, ``W31``, ``W32``)
    ``exclude_sensors`` channels left out of the default set: a dataset's metadata names
                    those that do not follow their stated definition (``not_physical`` of
                    a C-MAPSS import: its ``Ps30``) [()]
    ``noise_scale`` multiplier of the noise std in ``R`` [1]
    ``noise``       ``"model"`` (the simulator's documented noise) or ``"data"`` (each
                    channel's noise per operating condition from the calibrated data;
                    module docstring) ["model"]
    ``noise_table`` the data's noise, ``((condition, channel, std), ...)``: filled by
                    :func:`calibration.calibrate_fleet.calibrate_fleet` when ``noise`` is
                    ``"data"`` and recorded with the settings [()]
    ``model_error`` the model's own error, a relative std added in quadrature [0]
    ``drift``       random-walk std of theta per sqrt(hour of operation) (``hyprog calibrate
                    --drift``, the pipeline's ``[calibrate] drift``) [1e-3]
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
    exclude_sensors: tuple = ()
    noise_scale: float = 1.0
    noise: str = "model"
    noise_table: tuple = ()
    model_error: float = 0.0
    drift: float = DEFAULT_DRIFT_STD_PER_SQRT_H
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
            if len(set(sensors)) != len(sensors):
                raise InputError(f"sensors listed twice: {', '.join(sensors)}")
            bad = [c for c in sensors if c not in OUTPUT_NAMES]
            if bad:
                raise InputError(f"unknown sensor(s) {', '.join(bad)}; measured channels are "
                                 f"{', '.join(XS_NAMES)}, and with noise='data' any output "
                                 f"the model computes ({', '.join(DERIVED_SENSORS)})")
            derived = [c for c in sensors if c not in XS_NAMES]
            if derived and self.noise != "data":
                raise InputError(f"sensor(s) {', '.join(derived)}: the simulator documents the "
                                 "noise of the measured channels x_s only; use the data's "
                                 "noise (noise='data', --noise data)")
            if not sensors:
                raise InputError("calibration: no sensor to use")
        object.__setattr__(self, "exclude_sensors", tuple(self.exclude_sensors))
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
        if not np.all(np.isfinite(_vec(self.prior_mean, len(params), "prior_mean"))):
            raise InputError(f"prior_mean must be finite, got {self.prior_mean}")
        std = _vec(self.prior_std, len(params), "prior_std")
        if not np.all(np.isfinite(std) & (std > 0)):
            raise InputError(f"prior_std must be positive and finite, got {self.prior_std}")
        for name in ("noise_scale", "sample_period_s", "observability_rtol",
                     "observability_max_std"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{name} must be positive and finite, got {v}")
        if int(self.observability_samples) != self.observability_samples \
                or self.observability_samples < 1:
            raise InputError("observability_samples must be an integer >= 1, got "
                             f"{self.observability_samples}")
        if self.noise not in ("model", "data"):
            raise InputError(f"noise must be 'model' or 'data', got {self.noise!r}")
        table = tuple((int(c), str(ch), float(v)) for c, ch, v in self.noise_table)
        if table and self.noise != "data":
            raise InputError("noise_table is the data's noise: it needs noise='data'")
        if any(not (np.isfinite(v) and v > 0) for *_, v in table):
            raise InputError("noise_table: every std must be positive and finite")
        object.__setattr__(self, "noise_table", table)
        object.__setattr__(self, "model_error", check_model_error(self.model_error))
        if not (self.drift >= 0 and np.isfinite(self.drift)):
            raise InputError(f"drift must be >= 0 and finite, got {self.drift}")
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

    def data_noise(self, condition: np.ndarray, sensors, where: str = "") -> np.ndarray:
        """(N, len(sensors)) noise std of the data at each sample's operating ``condition``
        from :attr:`noise_table` (``noise="data"``); a condition or channel the table lacks
        is an error naming it."""
        table = {(c, ch): v for c, ch, v in self.noise_table}
        conds = np.unique(condition)
        missing = [(int(c), ch) for c in conds for ch in sensors if (int(c), ch) not in table]
        if missing:
            c, ch = missing[0]
            raise InputError(f"{where}condition {c}, channel {ch}: no noise estimate in the "
                             "data's noise table (noise='data')")
        out = np.empty((len(condition), len(sensors)))
        for c in conds:
            rows = condition == c
            out[rows] = [table[(int(c), ch)] for ch in sensors]
        return out

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

    def full_theta(self, theta_est: np.ndarray, index=None) -> np.ndarray:
        """(..., k) estimated values -> (..., 10) full theta: :meth:`theta_base` with the
        values put at ``index`` (positions in THETA_NAMES; default :attr:`param_index`, or a
        subset of it when only the observable parameters are estimated)."""
        theta_est = np.asarray(theta_est, float)
        th = np.broadcast_to(self.theta_base(), (*theta_est.shape[:-1], N_THETA)).copy()
        th[..., self.param_index if index is None else index] = theta_est
        return th

    def resolve_sensors(self, columns) -> tuple:
        """The sensors to use for data with ``columns``: the requested ones (each must be
        present) or every measured channel present. A column whose name looks like a misspelt
        measured channel that is absent (``T3O`` for ``T30``, ``t30``) is an error with the
        suggestion (:func:`misspelt_channels`)."""
        typos = misspelt_channels(columns)
        if typos:
            raise InputError("; ".join(f"column {c!r} looks like a misspelt {x!r} (the"
                                       f" measured channel {x} is absent); rename it"
                                       for c, x in typos))
        if self.sensors is None:
            sensors = tuple(c for c in XS_NAMES
                            if c in columns and c not in self.exclude_sensors)
            if not sensors:
                raise InputError(f"data: none of the measured channels {', '.join(XS_NAMES)}"
                                 " is present" + (f" (left out: {', '.join(self.exclude_sensors)})"
                                                  if self.exclude_sensors else ""))
            return sensors
        absent = [c for c in self.sensors if c not in columns]
        if absent:
            raise InputError(f"missing sensor column(s) {', '.join(absent)}")
        return self.sensors

    def for_dataset(self, meta: dict) -> CalibrationSetup:
        """This setup for a dataset with metadata ``meta``: when no sensors were chosen, the
        channels its ``not_physical`` entry names are added to :attr:`exclude_sensors`."""
        extra = [c for c in (meta.get("not_physical") or {}) if c not in self.exclude_sensors]
        if self.sensors is not None or not extra:
            return self
        return replace(self, exclude_sensors=(*self.exclude_sensors, *extra))

    def with_params(self, params) -> CalibrationSetup:
        """The same setup for a subset of its parameters (prior values carried over); a
        parameter left out (an unobservable one) is held at its prior mean, added to
        :attr:`theta_fixed`, by every estimator alike."""
        params = tuple(params)
        pm, ps = self.prior_mean_vec(), self.prior_std_vec()
        sel = [self.params.index(q) for q in params]
        held = {**dict(self.theta_fixed),
                **{q: float(m) for q, m in zip(self.params, pm, strict=True)
                   if q not in params}}
        return replace(self, params=params, prior_mean=tuple(pm[sel]), prior_std=tuple(ps[sel]),
                       theta_fixed=held)
