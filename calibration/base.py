"""One interface for every estimator of the health parameters ``theta``.

An estimator takes one unit's time series (a DataFrame with the N-CMAPSS names: ``w`` columns
``alt Mach TRA T2``, the measured channels it uses, optionally ``t`` and ``cycle``) and a
:class:`setup.CalibrationSetup`, and returns a :class:`result.CalibrationResult`:
``theta_hat(t)``, its standard deviation and covariance, ``x_hat`` for every measured and
virtual channel, normalised residuals and diagnostics. Estimators are looked up by name in
:data:`ESTIMATORS` (``ukf``, ``ekf``, ``mhe``, ``map_cycle``) through :func:`get_estimator`.

The pieces every estimator shares live in their own modules: the state-space model and the
setup (:mod:`calibration.estimation_setup`), a unit's checked arrays (:mod:`calibration.series`),
the observability check (:mod:`calibration.observability`) and the result
(:mod:`calibration.result`). An estimator sees the engine only through
:class:`engine_model.solver.interface.SteadyStateModel`.
"""

from __future__ import annotations

import importlib
import inspect
import time
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence

import pandas as pd

from engine_model.runtime.shared_model import default_model
from engine_model.solver.interface import SteadyStateModel
from engine_model.validation import InputError

from .estimation_setup import CalibrationSetup
from .result import CalibrationResult


class Estimator(ABC):
    """Base class of the estimators. ``estimate`` runs one unit; ``estimate_many`` runs a
    list of units (default: one after the other; the filters run them in lockstep).

    Subclasses set ``name`` and take the engine model (default :func:`default_model`) and
    their own options as keyword arguments of ``__init__``.
    """

    name: str = "?"

    def __init__(self, model: SteadyStateModel | None = None):
        self.model: SteadyStateModel = model if model is not None else default_model()

    #: Whether :meth:`estimate` warns (:class:`~calibration.UnobservableWarning`) of each
    #: unit's unobservable parameters; a fleet driver that reports one summary for the fleet
    #: (:func:`~calibration.calibrate_fleet.calibrate_fleet`) switches it off on its instance.
    warn_unobservable: bool = True

    @classmethod
    def option_names(cls) -> set[str]:
        """The options ``__init__`` takes by name (besides the model); ``*args`` and
        ``**kwargs`` are not options of those names (see :meth:`check_options`)."""
        return {n for n, p in inspect.signature(cls.__init__).parameters.items()
                if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)} - {"self", "model"}

    @classmethod
    def takes_any_option(cls) -> bool:
        """Whether ``__init__`` takes ``**kwargs`` (then no option name can be refused)."""
        return any(p.kind is p.VAR_KEYWORD
                   for p in inspect.signature(cls.__init__).parameters.values())

    @classmethod
    def check_options(cls, options: dict) -> None:
        """Refuse ``options`` this estimator does not take, before any work (building the
        estimator builds the engine model, which a first run compiles). Subclasses whose
        options carry rules of their own check those too."""
        unknown = [] if cls.takes_any_option() else sorted(set(options) - cls.option_names())
        if unknown:
            raise InputError(f"calibration method {cls.name!r}: no option "
                             f"{', '.join(unknown)}")

    @classmethod
    def check_setup(cls, setup: CalibrationSetup) -> None:
        """Refuse a ``setup`` this estimator cannot run, before any work (every setup by
        default; the MHE reads the measured channels ``x_s`` only)."""
        return None

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
