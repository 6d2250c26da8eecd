"""What defines a training run: :class:`TrainConfig` (stored with every model) and the
networks' defaults, without importing torch (a configuration is read, checked and written
without loading the training machinery).

The paper's settings (Sec. 4.3-4.4): the FNN sees one time step and trains at most 60
epochs, the CNN a window of 50 samples and at most 30 epochs; mini-batches of 1024, constant
learning rate 1e-3, early-stopping patience 5, validation on 10 % of the flights
(:data:`PAPER_RECIPE`, what the paper experiment trains with). Those settings were made for
about 5 M samples (some 5,000 optimiser steps an epoch); a C-MAPSS subset has 20 k rows and one
sample per cycle, where 30 epochs at batch 1024 are some 500 steps. The defaults therefore
follow the size of the data (:meth:`TrainConfig.sized`, applied once the training windows
are known; the model stores the values used):

- ``validation="auto"``: whole held-out units (``"units"``) whenever there are at least two
  training units (issue 30: validation flights of units already trained on measure
  interpolation inside those units, not the prediction of an unseen engine; on ``ds02`` the
  paper's flight validation and the test RMSE were uncorrelated, Spearman 0.01 over 38 runs);
  the paper's flights with a single training unit. The paper experiment keeps its flights
  (:data:`PAPER_RECIPE`).
- ``batch_size=None``: the paper's 1024 when that still gives :data:`MIN_BATCHES` batches an
  epoch, else the largest power of two that does (at least :data:`MIN_BATCH`).
- ``epochs=None``: the model's default (:data:`DEFAULT_EPOCHS`), raised so that the budget is
  at least :data:`MIN_STEPS` optimiser steps.
- ``patience=None``: 5 epochs (the paper's), raised to at least :data:`PATIENCE_STEPS`
  optimiser steps, so that a small table does not stop on a few noisy epochs.
- ``schedule="plateau"``: the learning rate falls tenfold when the validation loss has not
  improved for half the patience, down to 1 % of ``lr`` (``"constant"``: the paper's).
- ``normalise="auto"``: ``"condition"`` (standardised per operating condition,
  :mod:`.scaling`; the standard for C-MAPSS FD002 / FD004) when the table has a ``condition``
  column whose training rows all carry a condition (none is 0) and hold more than one;
  ``"minmax"`` (the paper's min-max scaling over the fleet) otherwise.
- ``drop_constant=True``: input columns constant over the training rows (within every
  condition, with ``normalise="condition"``) are dropped and recorded, and so are the
  operating settings when every training row flies one operating condition (they are then
  measurement noise around it; :func:`prognostics.training.training_conditions`).

Flight models (:data:`FLIGHT_MODELS`, issue 30): ``tcn`` reads the last ``window`` flights
(default 20) of the flight table (:func:`prognostics.flights.flight_table`, built from a sample
table by training and prediction themselves); ``trend`` is the same network learning a
correction to the physics trend baseline (:mod:`prognostics.baseline`): its target is
``min(RUL, max_rul) - RUL_trend`` and its prediction ``RUL_trend + network``, with the trend
capped at ``trend_cap`` (None: the longest development life, as the baseline's prior).
Every flight gets a prediction (windows left-padded, :mod:`prognostics.windows`).

``similarity`` (:data:`LIBRARY_MODELS`) is no network: the training units' trajectories of
one health index (``inputs``, default ``HI_hat_rel``: the health index of θ̂ relative to the
unit's early life, the many-fleet study's choice over the absolute ``HI_hat``,
:mod:`prognostics.similarity`) are a library, and a unit's last ``window`` flights (default
10, the choice of ``ds02``'s development folds) are matched to it (Wang et al. 2008).
Nothing is optimised, so nothing stops early: it has no validation units, and the epoch,
batch, learning-rate, patience, schedule and normalisation fields do not apply (they are
recorded as given).

The numbers were set once, for C-MAPSS FD001, not per data set: :data:`MIN_BATCHES` 16 gives
Li et al.'s batch of 512 there, chosen over 128 on one cross-validation fold
(``benchmarks/cmapss.py``, data-driven DCNN, RMSE 15.4 against 16.9); :data:`MIN_STEPS` 5,000
keeps Li et al.'s 250 epochs; :data:`PATIENCE_STEPS` 2,000 (72 epochs there) is a judgement,
not a fit. At the paper's 5 M samples every rule gives the paper's value back.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import asdict, dataclass, replace

from engine_model.validation import InputError, check_seed

from .choices import (  # noqa: F401  (re-exported: the names every caller imports from here)
    FLIGHT_MODELS,
    LIBRARY_MODELS,
    MODEL_KINDS,
    NORMALISATIONS,
    SCHEDULES,
    VALIDATIONS,
)

DEFAULT_EPOCHS = {"fnn": 60, "cnn": 30, "dcnn": 250,  # dcnn: Li, Ding & Sun 2018
                  "tcn": 300, "trend": 300}
DEFAULT_WINDOW = {"fnn": 1, "cnn": 50, "dcnn": 30, "tcn": 20, "trend": 20, "similarity": 10}
#: the inputs of a model whose caller gives none (the CLI's and the estimator's default)
DEFAULT_INPUTS = {"similarity": "HI_hat_rel"}
PAPER_BATCH, PAPER_PATIENCE = 1024, 5
MIN_BATCHES = 16
MIN_BATCH = 32
MIN_STEPS = 5_000
PATIENCE_STEPS = 2_000
#: The paper's training recipe (module docstring), for :func:`dataclasses.replace`.
PAPER_RECIPE = {"batch_size": PAPER_BATCH, "patience": PAPER_PATIENCE, "schedule": "constant",
                "normalise": "minmax", "drop_constant": False, "validation": "flights"}


@dataclass(frozen=True)
class TrainConfig:
    """Everything that defines a training run (stored with the model)."""

    model: str = "cnn"
    inputs: str = "hybrid"
    window: int | None = None  # None: 50 for the CNN, 1 (one time step) for the FNN
    stride: int = 1
    max_rul: float | None = None
    seed: int = 0
    epochs: int | None = None  # None: by data size (module docstring)
    batch_size: int | None = None  # None: by data size
    lr: float = 1e-3
    patience: int | None = None  # None: by data size
    schedule: str = "plateau"
    normalise: str = "auto"
    drop_constant: bool = True
    val_fraction: float = 0.1
    validation: str = "auto"
    val_units: tuple[int, ...] | None = None
    units: tuple[int, ...] | None = None  # development units (default: the metadata's)
    test_units: tuple[int, ...] | None = None  # default: the metadata's
    conformal_units: tuple[int, ...] = ()
    alpha: float = 0.1
    device: str = "auto"
    trend_cap: float | None = None  # the trend model's cap (None: longest development life)

    @property
    def per_flight(self) -> bool:
        """The model reads a flight table (:data:`FLIGHT_MODELS`)."""
        return self.model in FLIGHT_MODELS

    @property
    def reads_flights(self) -> bool:
        """Training and prediction build the flight table of the rows
        (:func:`prognostics.training.flight_frame`): a flight model, or inputs that name a
        health group (:func:`prognostics.features.health_groups_of`; a sample model reads
        them on a table with one row per cycle, such as C-MAPSS, whose flight table has the
        same rows)."""
        from .features import health_groups_of

        return self.per_flight or bool(health_groups_of(self.inputs))

    def resolved(self, names: Mapping[str, str] | None = None) -> TrainConfig:
        """The window filled in and values checked; the size rules (epochs, batch size,
        patience, validation) stay None / "auto" until :meth:`sized`. ``names``: how a field
        is named in an error (the CLI passes its option names, ``{"epochs": "--epochs"}``);
        a field not in it is named as the field."""
        def called(field: str) -> str:
            return (names or {}).get(field, field)

        if self.model not in MODEL_KINDS:
            raise InputError(f"unknown model {self.model!r}; one of {', '.join(MODEL_KINDS)}")
        for name, allowed in (("schedule", SCHEDULES), ("normalise", NORMALISATIONS),
                              ("validation", VALIDATIONS)):
            if getattr(self, name) not in allowed:
                raise InputError(f"{called(name)} must be one of {', '.join(allowed)}, got "
                                 f"{getattr(self, name)!r}")
        c = replace(self,
                    window=DEFAULT_WINDOW[self.model] if self.window is None else self.window)
        check_seed(c.seed, called("seed"))
        if c.device not in ("auto", "cpu", "cuda"):
            raise InputError(f"{called('device')} must be auto, cpu or cuda, got {c.device!r}")
        if not 0.0 <= c.val_fraction < 1.0:  # (NaN fails too)
            raise InputError(f"{called('val_fraction')} (validation fraction) must lie in "
                             f"[0, 1), got {c.val_fraction}")
        for name in ("window", "stride", "epochs", "batch_size", "patience"):
            v = getattr(c, name)
            if v is not None and int(v) < 1:
                raise InputError(f"{called(name)} must be >= 1, got {v}")
        for name in ("max_rul", "trend_cap"):
            v = getattr(c, name)
            if v is not None and not (v > 0 and v < float("inf")):
                raise InputError(f"{called(name)} must be a positive finite number, got {v}")
        if not (c.lr > 0 and c.lr < float("inf")):
            raise InputError(f"{called('lr')} (learning rate) must be a positive finite number, "
                             f"got {c.lr}")
        if not 0.0 < c.alpha < 1.0:
            raise InputError(f"{called('alpha')} (interval miscoverage) must lie in (0, 1), "
                             f"got {c.alpha}")
        return c

    def validation_for(self, n_units: int) -> str:
        """``validation`` with ``"auto"`` decided for ``n_units`` training units (module
        docstring)."""
        if self.validation != "auto":
            return self.validation
        return "units" if n_units >= 2 else "flights"

    def sized(self, n_windows: int, n_units: int) -> TrainConfig:
        """The size rules of the module docstring for ``n_windows`` training windows (an
        estimate before the validation split is fine: the rules are coarse) and ``n_units``
        training units."""
        c = self.resolved()
        batch = c.batch_size
        if batch is None:
            batch = PAPER_BATCH
            while batch > MIN_BATCH and n_windows < MIN_BATCHES * batch:
                batch //= 2
        steps = max(1, -(-max(n_windows, 1) // batch))  # optimiser steps an epoch
        epochs = c.epochs if c.epochs is not None else \
            max(DEFAULT_EPOCHS[c.model], -(-MIN_STEPS // steps))
        patience = c.patience if c.patience is not None else \
            max(PAPER_PATIENCE, -(-PATIENCE_STEPS // steps))
        return replace(c, batch_size=batch, epochs=epochs, patience=patience,
                       validation=c.validation_for(n_units))

    def to_dict(self) -> dict:
        """The fields as JSON values. ``trend_cap`` is left out while None (it is the trend
        model's, added after runs had been keyed by this dict: their keys stay valid)."""
        d = asdict(self)
        if d["trend_cap"] is None:
            del d["trend_cap"]
        for k in ("val_units", "units", "test_units", "conformal_units"):
            if d[k] is not None:
                d[k] = [int(u) for u in d[k]]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TrainConfig:
        known = {f for f in cls.__dataclass_fields__}
        unknown = sorted(set(d) - known)
        if unknown:
            raise InputError(f"training config: unknown key(s) {', '.join(unknown)}")
        kw = dict(d)
        for k in ("val_units", "units", "test_units", "conformal_units"):
            if kw.get(k) is not None:
                kw[k] = tuple(int(u) for u in kw[k])
        return cls(**kw)
