"""Calibration of the engine model: estimators of the health parameters ``theta``.

One interface (:mod:`calibration.base`; setup, data, observability and result in
:mod:`calibration.estimation_setup`, :mod:`calibration.series`, :mod:`calibration.observability`,
:mod:`calibration.result`): ``get_estimator(name).estimate(df_unit, setup)``
returns a :class:`CalibrationResult`; a whole fleet, :func:`calibrate` (a
:class:`~engine_model.datasets.Dataset` in, its feature table out) or
:func:`calibration.calibrate_fleet.calibrate_fleet` (to disk, resumable, in parallel; the
submodule keeps that name, so it is not re-exported here). Methods: ``ukf``
(:mod:`calibration.ukf`), ``ekf``
(:mod:`calibration.ekf`), ``mhe`` and ``map_cycle`` (:mod:`calibration.mhe`). Fleets:
:mod:`calibration.calibrate_fleet`; comparison against truth and the Cramér-Rao bound:
:mod:`calibration.compare`, :mod:`calibration.crb`.
"""

from .base import ESTIMATORS, Estimator, estimator_class, get_estimator
from .calibrate_fleet import FleetRun, calibrate
from .estimation_setup import CalibrationSetup
from .observability import UnobservableError, UnobservableWarning
from .result import CalibrationResult

__all__ = ["ESTIMATORS", "CalibrationResult", "CalibrationSetup", "Estimator", "FleetRun",
           "UnobservableError", "UnobservableWarning", "calibrate", "estimator_class",
           "get_estimator"]
