"""Calibration of the engine model: estimators of the health parameters ``theta``.

One interface (:mod:`calibration.base`): ``get_estimator(name).estimate(df_unit, setup)``
returns a :class:`CalibrationResult`. Methods: ``ukf`` (:mod:`calibration.ukf`), ``ekf``
(:mod:`calibration.ekf`), ``mhe`` and ``map_cycle`` (:mod:`calibration.mhe`). Fleets:
:mod:`calibration.fleet`; comparison against truth and the Cramér-Rao bound:
:mod:`calibration.compare`, :mod:`calibration.crb`.
"""

from .base import (
    ESTIMATORS,
    CalibrationResult,
    CalibrationSetup,
    Estimator,
    UnobservableError,
    UnobservableWarning,
    get_estimator,
)

__all__ = ["ESTIMATORS", "CalibrationResult", "CalibrationSetup", "Estimator",
           "UnobservableError", "UnobservableWarning", "get_estimator"]
