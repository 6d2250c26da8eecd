"""The RUL model as an estimator: ``RulEstimator(...).fit(data).predict(data)``, with ``save`` /
``load``, as scikit-learn and PyTorch Lightning users expect.

The options are those of :class:`~.train_config.TrainConfig` (the same names as the CLI's
``hyprog train`` flags and the pipeline's ``[train]`` table), given as keywords; ``fit``
trains one network per seed (:func:`.ensemble.fit`), ``predict`` returns the per-sample
prediction frame (:meth:`.ensemble.RulModel.predict`), ``evaluate`` an
:class:`~.evaluation.Evaluation` on test units, and ``save`` / ``load`` use the safe checkpoint
format of :mod:`.checkpoint`::

    from calibration import calibrate
    from engine_model.datasets import load_sample
    from prognostics import RulEstimator

    features = calibrate(load_sample(), "ukf")
    est = RulEstimator(model="cnn", inputs="hybrid", epochs=5).fit(features)
    result = est.evaluate(features)          # the metadata's test units
    print(result.rmse, result.to_frame())
    est.save("models/cnn")
    same = RulEstimator.load("models/cnn")

Data may be a :class:`~engine_model.datasets.Dataset` (its metadata names the development
and test units) or a DataFrame (then ``units`` / ``test_units`` are given as options or
arguments). Fitting never touches the test units; validation and early stopping use whole
development units (``validation="auto"``; with a single training unit, 10 % of its flights:
:meth:`~prognostics.train_config.TrainConfig.validation_for`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import fields, replace

import pandas as pd

from engine_model.datasets import Dataset
from engine_model.validation import InputError

from .checkpoint import load_model, save_model
from .ensemble import RulModel, fit
from .evaluation import Evaluation
from .train_config import DEFAULT_INPUTS, LIBRARY_MODELS, TrainConfig


def _frame_and_metadata(data) -> tuple[pd.DataFrame, dict, str]:
    if isinstance(data, Dataset):
        return data.frame, data.metadata, data.source
    if isinstance(data, pd.DataFrame):
        return data, {}, "table"
    raise InputError(f"expected a Dataset or a DataFrame, got {type(data).__name__}")


class RulEstimator:
    """A RUL model with the estimator interface (module docstring).

    Parameters are :class:`TrainConfig`'s fields (``model``, ``inputs``, ``window``,
    ``max_rul``, ``epochs``, ``lr``, ``conformal_units``, ...), checked when given;
    ``ensemble`` networks are trained, seeds ``seed .. seed + ensemble - 1``, on one
    validation split (the one ``seed`` draws: :func:`.ensemble.fit`). After
    :meth:`fit`, ``model_`` is the trained :class:`~.ensemble.RulModel`.
    """

    def __init__(self, *, ensemble: int = 1, **options) -> None:
        known = {f.name for f in fields(TrainConfig)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise InputError(f"RulEstimator: unknown option(s) {', '.join(unknown)}; known: "
                             f"{', '.join(sorted(known))}")
        if ensemble < 1:
            raise InputError(f"RulEstimator: ensemble must be >= 1, got {ensemble}")
        if ensemble > 1 and options.get("model") in LIBRARY_MODELS:
            raise InputError(f"RulEstimator: the {options['model']} model has no network and "
                             f"nothing random: ensemble {ensemble} is not one")
        if "inputs" not in options and options.get("model") in DEFAULT_INPUTS:
            options["inputs"] = DEFAULT_INPUTS[options["model"]]
        self.config = TrainConfig(**options)
        self.config.resolved()  # bad values now, not after training
        self.ensemble = ensemble
        self.model_: RulModel | None = None

    def __repr__(self) -> str:
        given = {f.name: getattr(self.config, f.name) for f in fields(TrainConfig)
                 if getattr(self.config, f.name) != f.default}
        state = "fitted" if self.model_ is not None else "not fitted"
        return (f"RulEstimator({', '.join(f'{k}={v!r}' for k, v in given.items())}"
                f"{', ' if given else ''}ensemble={self.ensemble}) [{state}]")

    def fit(self, data: Dataset | pd.DataFrame, quiet: bool = True) -> RulEstimator:
        """Train on the development units of ``data`` (the metadata's, or the ``units``
        option); returns ``self``."""
        frame, metadata, source = _frame_and_metadata(data)
        seeds = range(self.config.seed, self.config.seed + self.ensemble)
        self.model_ = fit(frame, metadata, self.config, seeds=seeds, quiet=quiet,
                          source=source)
        return self

    @property
    def model(self) -> RulModel:
        """The trained model (an error before :meth:`fit` or :meth:`load`)."""
        if self.model_ is None:
            raise InputError("RulEstimator: not fitted yet (call fit or load)")
        return self.model_

    def predict(self, data: Dataset | pd.DataFrame, units: Sequence[int] | None = None,
                device: str = "cpu") -> pd.DataFrame:
        """Per-sample predictions (:meth:`.ensemble.RulModel.predict`): ``RUL_pred``, and
        ``RUL_std`` / ``RUL_lower`` / ``RUL_upper`` where the model has them."""
        model = self.model
        frame, _, source = _frame_and_metadata(data)
        return model.predict(frame, units, device, source)

    def evaluate(self, data: Dataset | pd.DataFrame, units: Sequence[int] | None = None,
                 device: str = "cpu") -> Evaluation:
        """Metrics on ``units`` (default: the metadata's test units, else the
        ``test_units`` option)."""
        model = self.model
        frame, metadata, source = _frame_and_metadata(data)
        if units is None:
            units = list(model.config.test_units or metadata.get("test_units") or [])
        if not units:
            raise InputError(f"{source}: no test units: name them (units=...) or in the "
                             "metadata")
        metrics, pred = model.evaluate(frame, units, device, source)
        return Evaluation(metrics, pred)

    def save(self, path: str | os.PathLike, overwrite: bool = False) -> os.PathLike:
        """Write the trained model to the directory ``path`` (:mod:`.checkpoint`)."""
        return save_model(self.model, path, overwrite)

    @classmethod
    def load(cls, path: str | os.PathLike) -> RulEstimator:
        """A fitted estimator from a model directory (``hyprog train --out`` or
        :meth:`save`)."""
        model = load_model(path)
        est = cls.__new__(cls)
        est.config = replace(model.config)
        est.ensemble = max(1, len(model.members))  # a library model: one, no network
        est.model_ = model
        return est
