"""hyprog.prognostics: RUL prediction from feature tables (step 2-3 of the paper's Algorithm 1).

One job per module:

- :mod:`.features`     input sets by name (``data-driven``, ``hybrid``, ablations) -> columns
- :mod:`.scaling`      min-max scaling to [-1, 1] fitted on training units
- :mod:`.splits`       development / validation / conformal-calibration rows
- :mod:`.windows`      sliding windows as strided views (no per-window copy)
- :mod:`.flights`      flight tables: per-flight means and the health coordinates of theta_hat
- :mod:`.models`       the paper's FNN and 1-D CNN, Li et al.'s DCNN, the flight models' TCN
- :mod:`.choices`      the names a run chooses from (models, schedules, ...), import-free
- :mod:`.train_config` :class:`~.train_config.TrainConfig`, what defines a training run
- :mod:`.training`     the training loop of one network (AMSGrad, early stopping, seeds)
- :mod:`.ensemble`     a trained model (one network per seed), :func:`~.ensemble.fit`, predictions
- :mod:`.estimator`    :class:`~.estimator.RulEstimator`: ``fit`` / ``predict`` / ``evaluate`` /
  ``save`` / ``load``, the library's entry point
- :mod:`.evaluation`   :class:`~.evaluation.Evaluation`: metrics as a typed object,
  ``to_frame()`` / ``to_json()``
- :mod:`.conformal`    split-conformal prediction intervals
- :mod:`.checkpoint`   safe save / load (safetensors + JSON, SHA-256 checked)
- :mod:`.metrics`      RMSE, NASA score, per-cycle mean, prediction horizon, coverage
- :mod:`.cross_validation` folds of whole units, held-out units truncated as NASA's test
  files, one score per unit at its last cycle (the C-MAPSS protocol on training units)
- :mod:`.baseline`     physics-only RUL from the health-index trend of theta_hat
- :mod:`.floors`       predictors without a network (life, HI lookup, physics trend)
- :mod:`.outputs`      tables, JSON and text written atomically
- :mod:`.plots`        figures (matplotlib, Agg)

This is the pure ML library: it reads feature tables and never imports :mod:`calibration`, the
simulator (:mod:`engine_model.simulator`) or the application layer (:mod:`workflows`, which holds
the pipeline and the paper's experiment); the physics baseline uses the engine model through
:mod:`engine_model.physics.health_index`. It is the only package of hyprog that imports torch;
importing ``prognostics`` itself does not (the modules that need it import it).
"""

from importlib import import_module

# name -> submodule that defines it, imported on first use (PEP 562): ``import prognostics``
# stays free of torch, ``from prognostics import RulEstimator`` works
_LAZY = {
    "RulEstimator": "estimator",
    "Evaluation": "evaluation",
    "RulModel": "ensemble",
    "fit": "ensemble",
    "TrainConfig": "train_config",
    "load_model": "checkpoint",
    "save_model": "checkpoint",
    "evaluate_predictions": "metrics",
    "per_cycle": "metrics",
    "resolve_inputs": "features",
}

__all__ = sorted(_LAZY)


# the hook of engine_model.lazy_names, written out here: this ``__init__`` imports nothing of
# engine_model, so that ``hyprog --help`` (which reads prognostics.choices) never imports it
# (tests/test_cli.py)
def __getattr__(name: str):
    if name in _LAZY:
        value = getattr(import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
