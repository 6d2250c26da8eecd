"""A trained RUL model: one network per seed (an ensemble), its inputs, scaler and interval.

Prediction of a sample ``x`` by an ensemble of ``M`` members ``ŷ_1 .. ŷ_M`` (networks trained
with different seeds on the same data; Lakshminarayanan, Pritzel & Blundell, "Simple and
scalable predictive uncertainty estimation using deep ensembles", NeurIPS 2017)::

    ŷ(x) = (1/M) Σ_m ŷ_m(x)                      (RUL_pred)
    s(x) = sqrt( Σ_m (ŷ_m(x) - ŷ(x))² / (M - 1) )  (RUL_std, M >= 2)

The spread ``s`` measures disagreement between seeds (model uncertainty only); it is not a
calibrated interval. The calibrated interval is the split-conformal one (:mod:`.conformal`)
around ``ŷ``, present when the model was trained with conformal units:
``RUL_lower = max(ŷ - q̂, 0)``, ``RUL_upper = ŷ + q̂``.

A flight model (``tcn``, ``trend``) predicts once per flight, at its end, from the table's
flight table (:mod:`.flights`); on a sample table every sample of the flight carries that
prediction. The ``similarity`` model has no network and no members: its ``library``
(:class:`.similarity.SimilarityRul`) predicts each flight in the same way.

Prediction on a table uses the model's recorded columns (a missing one is an error naming
it), its scaler, and windows over each unit as a whole (:mod:`.windows`): a sample gets a
prediction when a full window ends at it; a unit shorter than the window is left-padded with
its first row and gets one prediction at its last sample.

A model trained on capped targets ``min(RUL, max_rul)`` has its predictions **capped like
the targets**: ``RUL_pred`` clipped to ``[0, max_rul]``, the convention of the C-MAPSS
literature (the network was never taught a RUL above the cap or below zero); the conformal
interval is calibrated on, and placed around, the clipped prediction; ``RUL_std`` is the
members' raw spread. Without a cap (the paper's setting) the ensemble mean is reported as it
is.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import torch
from torch import nn

from engine_model.validation import InputError

from .baseline import trend_per_flight
from .conformal import SplitConformal
from .features import TARGET, check_table, sort_table
from .flights import one_per_cycle, to_samples
from .metrics import evaluate_predictions
from .models import build_model
from .scaling import MinMaxScaler, Scaler, fit_scaler
from .similarity import SimilarityRul
from .splits import (
    CONFORMAL,
    TRAIN,
    VALIDATION,
    assign_roles,
    segments,
)
from .train_config import LIBRARY_MODELS, TrainConfig
from .training import (
    Member,
    deterministic,
    development_rows,
    predict_windows,
    prepare,
    progress_bar,
    resolve_device,
    rows_for,
    train_member,
)
from .windows import make_windows


@dataclass
class RulModel:
    """Members (one per seed), input columns, scaler, optional conformal interval; or, for
    the ``similarity`` model, no members and its ``library``."""

    config: TrainConfig
    columns: tuple[str, ...]
    scaler: Scaler
    members: list[Member]
    conformal: SplitConformal | None = None
    info: dict = field(default_factory=dict)  # e.g. the hyprog version it was trained with
    library: SimilarityRul | None = None

    @property
    def window(self) -> int:
        return int(self.config.window)

    @property
    def parameters(self) -> int:
        """Trainable parameters of one member (0 for a library model: nothing is trained)."""
        return self.members[0].parameters if self.members else 0

    def still_improving(self) -> list[str]:
        """A line for each member whose training ran every epoch allowed while its
        validation loss was still improving: its best epoch within the last half
        ``patience`` epochs (with the plateau schedule: the learning rate not yet lowered
        since; with a constant one the same count), so that the epoch cap, not early
        stopping, ended it. A best epoch earlier
        than that, with the loss flat since, is a converged run that early stopping was
        about to end: nothing is said (on FD003 with the defaults 88 of 225 runs reached the
        cap of 250, 16 with their best epoch in the last 25). Without validation nothing
        stops early, and nothing is said."""
        if not self.members:  # a library model trains nothing
            return []
        epochs, patience = int(self.config.epochs), int(self.config.patience)
        return [f"seed {m.seed}: training used all {epochs} epochs and the validation loss "
                f"was still improving (best epoch {m.best_epoch}): a larger --epochs may "
                f"give a better network"
                for m in self.members
                if len(m.history) >= epochs and m.history[-1]["val_loss"] is not None
                and len(m.history) - m.best_epoch < max(1, patience // 2)]

    def networks(self, device: torch.device | str = "cpu") -> list[nn.Module]:
        nets = []
        for m in self.members:
            net = build_model(self.config.model, len(self.columns), self.window)
            try:
                net.load_state_dict(m.state, strict=True)
            except RuntimeError as e:
                first = str(e).strip().splitlines()[0]
                raise InputError(f"model weights do not fit the network: {first}") from None
            nets.append(net.to(device))
        return nets

    def predict(self, df: pd.DataFrame, units: Sequence[int] | None = None,
                device: str = "cpu", source: str = "table",
                progress: Callable[[int, int], None] | None = None) -> pd.DataFrame:
        """Per-sample predictions (module docstring): ``unit``, ``cycle``, ``t`` and ``RUL``
        when the table has them, ``RUL_pred``, ``RUL_std`` (2+ members), ``RUL_lower`` and
        ``RUL_upper`` (with an interval). ``progress(done, total)`` counts windows times
        members as they are computed (the library model: flights, once, at the end)."""
        if units is not None:
            missing = sorted(set(int(u) for u in units) - set(df["unit"].unique().tolist()))
            if missing:
                raise InputError(f"{source}: unit(s) {', '.join(map(str, missing))} not in the "
                                 "table")
            df = df[df["unit"].isin([int(u) for u in units])]
        if len(df) == 0:
            raise InputError(f"{source}: no rows to predict")
        frame = samples = sort_table(df)
        cfg = self.config
        frame = rows_for(cfg, samples, self.info.get("health_effects", ()), source)
        missing = [c for c in self.columns if c not in frame.columns]
        if missing:
            raise InputError(f"{source}: missing input column(s) {', '.join(missing)} that the "
                             "model was trained on")
        check_table(frame, self.columns, source, target=False)
        _warn_late_start(frame, self.columns, source)
        x = self.scaler.transform_frame(frame, source=source)
        _warn_far_outside(x, self.scaler, source)
        if self.library is not None:
            return self._library_predict(frame, samples, progress)
        unit = frame["unit"].to_numpy()
        a, b = segments(unit, np.zeros(len(unit), np.int8))
        short = np.flatnonzero(b - a < self.window)
        if short.size and not cfg.per_flight:  # a flight model pads by design (windows.py)
            names = ", ".join(str(int(unit[a[i]])) for i in short[:10])
            more = f" and {short.size - 10} more" if short.size > 10 else ""
            warnings.warn(f"{source}: unit(s) {names}{more} have fewer samples than the "
                          f"window ({self.window}): each gets one prediction, at its last "
                          "sample, from a window left-padded with its first sample",
                          UserWarning, stacklevel=2)
        win = make_windows(x, a, b, self.window, 1, pad_all=cfg.per_flight)
        dev = resolve_device(device)
        nets = self.networks(dev)
        total, done = len(win) * len(nets), [0]

        def step(k: int) -> None:
            done[0] += k
            progress(done[0], total)

        with deterministic(dev):
            preds = np.stack([predict_windows(net, win, dev,
                                              progress=None if progress is None else step)
                              for net in nets])
        bad = ~np.isfinite(preds).all(axis=0)
        if bad.any():  # finite inputs so far outside the training range that float32 overflows
            i = int(win.rows[np.flatnonzero(bad)[0]])
            j = int(np.argmax(np.abs(x[i])))
            raise InputError(f"{source}: unit {int(unit[i])}, cycle {int(frame['cycle'].iloc[i])}"
                             f": the prediction is not finite; column {self.columns[j]} = "
                             f"{frame[self.columns[j]].iloc[i]:g} lies far outside the "
                             "training range")
        keep = [c for c in ("unit", "cycle", "t", TARGET, "hs") if c in frame.columns]
        out = frame[keep].iloc[win.rows].reset_index(drop=True)
        mean = preds.mean(axis=0)
        if cfg.model == "trend":
            mean = mean + trend_per_flight(frame, cfg.trend_cap, source)[win.rows]
        cap = cfg.max_rul
        out["RUL_pred"] = mean if cap is None else np.clip(mean, 0.0, cap)
        if len(preds) > 1:
            out["RUL_std"] = preds.std(axis=0, ddof=1)
        return self._finish(out, samples)

    def _finish(self, out: pd.DataFrame, samples: pd.DataFrame) -> pd.DataFrame:
        """The interval around ``out``'s predictions, and a flight model's flights carried to
        the samples of ``samples``."""
        if self.conformal is not None:
            out["RUL_lower"], out["RUL_upper"] = self.conformal.interval(out["RUL_pred"])
        if self.config.per_flight and not one_per_cycle(samples):
            out = to_samples(out, samples, [c for c in out.columns if c.startswith("RUL_")])
        return out

    def _library_predict(self, flights: pd.DataFrame, samples: pd.DataFrame,
                         progress: Callable[[int, int], None] | None) -> pd.DataFrame:
        """:meth:`predict` for the library model: every flight of ``flights``, capped and
        with the interval like a network's, carried to the samples of ``samples``."""
        out = self.library.predict(flights, self.config.max_rul)
        if progress is not None:
            progress(len(out), len(out))
        return self._finish(out, samples)

    def evaluate(self, df: pd.DataFrame, units: Sequence[int], device: str = "cpu",
                 source: str = "table", progress: Callable[[int, int], None] | None = None
                 ) -> tuple[dict, pd.DataFrame]:
        """Metrics of :func:`metrics.evaluate_predictions` on ``units`` and the predictions
        (``progress`` as in :meth:`predict`). Warns when a unit evaluated was one of the
        model's own training, validation or conformal units (``info["units"]``, recorded by
        :func:`fit` and the manifest), whose error is not a test error."""
        if TARGET not in df.columns:
            raise InputError(f"{source}: no {TARGET} column to evaluate against")
        rows = df[df["unit"].isin([int(u) for u in units])] if units is not None else df
        check_table(rows, [], source, target=True)  # the truth: finite, not negative
        used: dict[int, set] = {}
        for role, us in (self.info.get("units") or {}).items():
            for u in us:  # a unit can have two roles (validation on flights)
                used.setdefault(int(u), set()).add(role)
        seen = sorted({int(u) for u in rows["unit"].unique()} & set(used))
        if seen:
            roles = ", ".join(sorted(set().union(*(used[u] for u in seen))))
            warnings.warn(f"{source}: unit(s) {', '.join(map(str, seen[:10]))}"
                          f"{' ...' if len(seen) > 10 else ''} were used to train this model "
                          f"({roles}): their error is not a test error", UserWarning,
                          stacklevel=2)
        pred = self.predict(df, units, device, source, progress)
        return evaluate_predictions(pred), pred


def _warn_late_start(frame: pd.DataFrame, columns: Sequence[str], source: str) -> None:
    """Inputs relative to a unit's early life (``<q>_hat_rel``, ``HI_hat_rel``:
    :mod:`.flights`) take its first flights in the table as that early life: a unit whose
    first cycle is not 1 did not enter the table at entry into service, so its reference is
    mid-life health and the relative inputs understate its loss; warned, naming the units."""
    if not any(c.endswith("_rel") for c in columns):
        return
    first = frame.groupby("unit")["cycle"].min()
    late = first[first > 1]
    if len(late):
        names = ", ".join(f"{int(u)} (cycle {int(c)})" for u, c in late.iloc[:10].items())
        more = f" and {len(late) - 10} more" if len(late) > 10 else ""
        warnings.warn(f"{source}: unit(s) {names}{more} start after cycle 1: inputs relative "
                      "to early life take their first flights here as their early life",
                      UserWarning, stacklevel=3)


#: A scaled input this far outside [-1, 1] (the training range) is one training range beyond
#: either end: :func:`_warn_far_outside`
FAR_OUTSIDE = 3.0
#: ... in more than this fraction of the rows
FAR_FRACTION = 0.01


def _warn_far_outside(x: np.ndarray, scaler, source: str) -> None:
    """Warn when min-max scaled inputs lie more than one training range beyond it in more
    than 1 % of the rows (an FD001 model given FD002's six conditions predicted 0 for every
    row without a word). Standardised inputs (per condition) have no range to compare with,
    and a column constant in training scales to 0 whatever it reads (the training drops such
    columns by default, ``drop_constant``)."""
    if not isinstance(scaler, MinMaxScaler) or not len(x):
        return
    frac = np.mean(np.abs(x) > FAR_OUTSIDE, axis=0)
    cols = [c for c, f in zip(scaler.columns, frac, strict=True) if f > FAR_FRACTION]
    if cols:
        warnings.warn(f"{source}: input column(s) {', '.join(cols[:5])}"
                      f"{' ...' if len(cols) > 5 else ''} lie beyond the training range by "
                      f"more than that range in over {FAR_FRACTION:.0%} of the rows: the model "
                      "extrapolates (data of another engine or fleet?)", UserWarning,
                      stacklevel=3)


def trained_with(device: torch.device) -> dict:
    """What a run's bits depend on besides the seed and the data (:mod:`.training`): torch's
    version, the device and torch's CPU thread count. Recorded in the model's manifest."""
    return {"torch": torch.__version__, "device": device.type,
            "threads": torch.get_num_threads()}


def fit(df: pd.DataFrame, metadata: dict | None, config: TrainConfig,
        seeds: Sequence[int] | None = None, quiet: bool = True,
        source: str = "table") -> RulModel:
    """Train one network per seed (default: ``config.seed``) on ``df`` -> a
    :class:`RulModel` (with a conformal interval when ``config.conformal_units``).

    The members share one preparation: the validation (and conformal) units drawn by
    ``config.seed``, and the scaler fitted on the remaining training rows, so that one
    model has one set of columns and one scaler; they differ by their initialisation and
    batch order. An ensemble whose members each draw their own validation units (as
    ``benchmarks/cmapss.py`` cross-validates) is one ``fit`` per seed, with
    ``replace(config, seed=s)``, and the mean of their predictions.

    The ``similarity`` model trains nothing: :func:`fit_library` (``seeds`` do not apply)."""
    if config.model in LIBRARY_MODELS:
        n = 1 if seeds is None else len(list(seeds))
        if n > 1:
            raise InputError(f"{config.model}: no network and nothing random: one model, not "
                             f"an ensemble of {n}")
        return fit_library(df, metadata, config, source)
    prep = prepare(df, metadata, config, source)
    cfg = prep.config
    device = resolve_device(cfg.device)
    seeds = [cfg.seed] if seeds is None else [int(s) for s in seeds]
    if not seeds:
        raise InputError("no seeds to train")
    members = []
    for s in seeds:
        label = f"{cfg.model} {cfg.inputs} seed {s}"
        with progress_bar(len(prep.windows[TRAIN]), label, quiet) as (on_batch, on_epoch):
            members.append(train_member(prep, s, device, on_batch, on_epoch))
    unit = prep.frame["unit"].to_numpy()
    roles = {name: sorted({int(u) for u in unit[prep.roles == role]})
             for name, role in (("training", TRAIN), ("validation", VALIDATION),
                                ("conformal", CONFORMAL))}
    model = RulModel(cfg, tuple(prep.columns), prep.scaler, members,
                     info={"units": {k: v for k, v in roles.items() if v},
                           "dropped_constant": list(prep.dropped),
                           "health_effects": list(prep.health_effects),
                           "trained_with": trained_with(device)})
    conf = prep.windows.get(CONFORMAL)
    if conf is not None and len(conf):
        with deterministic(device):
            preds = np.mean([predict_windows(net, conf, device)
                             for net in model.networks(device)], axis=0)
        if prep.offset is not None:
            preds = preds + prep.offset[conf.rows]
        if cfg.max_rul is not None:
            preds = np.clip(preds, 0.0, cfg.max_rul)  # as RulModel.predict reports it
        y_true = prep.frame[TARGET].to_numpy(np.float64)[conf.rows]
        model.conformal = SplitConformal.calibrate(y_true, preds, cfg.alpha,
                                                   sorted(set(cfg.conformal_units)))
    return model


def fit_library(df: pd.DataFrame, metadata: dict | None, config: TrainConfig,
                source: str = "table") -> RulModel:
    """The ``similarity`` model (:mod:`.similarity`) of ``df``'s development units: their
    flight table with the health coordinates of the engine model θ̂ was calibrated with
    (:func:`.training.development_rows`), one health-index column (``config.inputs``), the
    library of every development unit but the conformal ones (their RUL capped at
    ``max_rul``), a min-max scaler of that column on the library's flights (for the warning
    on inputs far outside the training range), and, with conformal units, the split-conformal
    interval of the library's predictions on them. Nothing is optimised, so there are no
    validation units (refused when named) and no seeds."""
    if config.val_units or config.validation != "auto":
        raise InputError(f"{source}: the similarity model optimises nothing and stops nothing "
                         "early: it takes no validation units (every development unit joins "
                         "its library)")
    d = development_rows(df, metadata, config, source)
    cfg, flights, columns = d.config, d.frame, d.columns
    if len(columns) != 1:
        raise InputError(f"{source}: the similarity model reads one health index (inputs "
                         f"HI_hat, HI_hat_rel, or HI for the true θ); inputs {cfg.inputs!r} are "
                         f"{len(columns)} columns ({', '.join(columns[:6])}"
                         f"{' ...' if len(columns) > 6 else ''})")
    roles = assign_roles(flights["unit"].to_numpy(), flights["cycle"].to_numpy(), d.dev_units,
                         validation="flights", val_fraction=0.0,
                         conformal_units=cfg.conformal_units, source=source)
    in_library = roles == TRAIN
    unit = flights["unit"].to_numpy()
    library_units = sorted({int(u) for u in unit[in_library]})
    conformal = sorted({int(u) for u in unit[roles == CONFORMAL]})
    lib_flights = flights[in_library]
    if cfg.max_rul is not None:
        lib_flights = lib_flights.assign(**{TARGET: np.minimum(lib_flights[TARGET],
                                                               cfg.max_rul)})
    longest = int(lib_flights.groupby("unit").size().max())
    if cfg.window > longest:  # (the conformal units may be longer)
        raise InputError(f"{source}: window {cfg.window} is longer than the longest library "
                         f"unit ({longest} flights)")
    library = SimilarityRul.fit(lib_flights, cfg.window, columns[0])
    scaler = fit_scaler("minmax", flights, columns, in_library, source)
    units = {"training": library_units, **({"conformal": conformal} if conformal else {})}
    model = RulModel(cfg, tuple(columns), scaler, [], library=library,
                     info={"units": units, "dropped_constant": [],
                           "health_effects": list(d.health_effects)})
    if conformal:
        held = flights[flights["unit"].isin(conformal)]
        pred = library.predict(held, cfg.max_rul)
        model.conformal = SplitConformal.calibrate(pred[TARGET].to_numpy(np.float64),
                                                   pred["RUL_pred"].to_numpy(np.float64),
                                                   cfg.alpha, conformal)
    return model
