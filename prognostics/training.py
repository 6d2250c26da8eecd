"""Training of the prognostics networks (the paper, Sec. 4.4), reproducible bit for bit.

Set-up (paper): mean-squared error on RUL in cycles; Adam with AMSGrad (Reddi, Kale & Kumar,
ICLR 2018), learning rate 1e-3, mini-batches of 1024; Xavier initialisation; at most 60 (FNN)
or 30 (CNN) epochs; early stopping with patience 5 on the validation loss, the weights of the
best validation epoch restored at the end.

Pipeline of :func:`prognostics.ensemble.fit` (this module trains one network per seed; the
ensemble module assembles them into a :class:`~prognostics.ensemble.RulModel`):

1. development and test units (:func:`splits.development_and_test_units`), the input columns
   (:func:`features.resolve_inputs`), roles per row (:func:`splits.assign_roles`: validation
   flights or units, conformal units);
2. the scaler (min-max, or per operating condition) fitted on the **training rows only**
   (:mod:`.scaling`); with ``drop_constant``, input columns constant over those rows are
   dropped, and so are the operating settings when those rows fly a single operating
   condition (:func:`training_conditions`) (:attr:`Prepared.dropped`);
3. windows inside each unit-and-role segment (:mod:`.windows`; the flight models of
   :mod:`.train_config` read the flight table of the rows, :func:`flight_frame`, as does a
   sample model whose inputs name a health group, on a table with one row per cycle:
   :func:`rows_for`; a flight model's windows run over each unit's whole history, every
   flight ending one, which takes that flight's role), target ``min(RUL, max_rul)`` (minus the
   physics trend for the ``trend`` model, :func:`.baseline.trend_per_flight`) at the window's
   last row (``max_rul`` None: no cap, the paper's setting); the size rules of
   :mod:`.train_config` fill in the batch size, epochs and patience from the number of
   training windows;
4. per seed: initialise, train (learning rate held, or cut tenfold on a validation plateau),
   early-stop, restore the best epoch;
5. with conformal units: the ensemble mean on their windows calibrates a split-conformal
   interval (:mod:`.conformal`).

Reproducibility: the initial weights come from a generator seeded by the seed, the batch order
from a second generator seeded by the seed + 1 (a CPU ``torch.Generator``, also when training
on CUDA), dropout masks (DCNN, TCN) from torch's global generator seeded by the seed + 2 when the
member starts, there are no DataLoader workers, and :func:`deterministic` switches on torch's
deterministic algorithms (and deterministic cuBLAS / cuDNN on CUDA). Same seed, same data,
same device and thread count -> the same weights and losses, bit for bit (a model's manifest
records them: ``trained_with``, :mod:`.checkpoint`).

Device: ``auto`` is CUDA when available, else CPU; ``cuda`` without a GPU is an error. On CPU
torch's own thread count is used (both cores of a 2-core machine by default).
"""

from __future__ import annotations

import copy
import os
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace

import numpy as np
import pandas as pd
import torch
from torch import nn

from engine_model.channels import THETA_NAMES, W_NAMES
from engine_model.validation import InputError

from .baseline import health_effects, trend_per_flight
from .features import (
    TARGET,
    check_table,
    health_groups_of,
    resolve_inputs,
    sort_table,
    unobservable_columns,
)
from .flights import flight_table, one_per_cycle, unit_lives
from .models import build_model, parameter_count
from .scaling import CONDITION, Scaler, fit_scaler
from .splits import (
    CONFORMAL,
    TRAIN,
    VALIDATION,
    assign_roles,
    development_and_test_units,
    segments,
)
from .train_config import TrainConfig
from .windows import Windows, make_windows

EVAL_BATCH = 8192
PLATEAU_FACTOR = 0.1  # learning rate x 0.1 on a plateau of half the patience ...
PLATEAU_FLOOR = 0.01  # ... down to 1 % of the configured rate


@dataclass
class Member:
    """One trained network: its seed, best weights (CPU tensors) and training history."""

    seed: int
    state: dict[str, torch.Tensor]
    history: list[dict] = field(default_factory=list)
    best_epoch: int = 0
    parameters: int = 0


@dataclass
class Prepared:
    """Scaled development rows, their roles and windows (steps 1-3 of the module docstring)."""

    config: TrainConfig
    columns: list[str]
    scaler: Scaler
    frame: pd.DataFrame  # the development rows (unit, cycle, t, RUL), sorted
    roles: np.ndarray
    windows: dict[int, Windows]
    dev_units: list[int]
    test_units: list[int]
    dropped: list[str] = field(default_factory=list)  # constant input columns left out
    offset: np.ndarray | None = None  # the trend model's offset per row of ``frame``
    health_effects: tuple[str, ...] = ()  # the engine model of the health coordinates


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cpu":
        return torch.device("cpu")
    if name == "cuda":
        if not torch.cuda.is_available():
            raise InputError("device cuda: no CUDA device available (use --device cpu or auto)")
        return torch.device("cuda")
    raise InputError(f"device must be auto, cpu or cuda, got {name!r}")


@contextmanager
def deterministic(device: torch.device) -> Iterator[None]:
    """Torch's deterministic algorithms (and cuBLAS / cuDNN settings on CUDA) for the block."""
    was = torch.are_deterministic_algorithms_enabled()
    cudnn = (torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark)
    if device.type == "cuda":
        os.environ.setdefault("CUBLAS_WORKSPACE_CONFIG", ":4096:8")
        torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark = True, False
    torch.use_deterministic_algorithms(True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(was)
        torch.backends.cudnn.deterministic, torch.backends.cudnn.benchmark = cudnn


def flight_frame(df: pd.DataFrame, source: str = "table",
                 effects: Sequence[str] = ()) -> pd.DataFrame:
    """The flight table of ``df`` (:func:`prognostics.flights.flight_table`), with the health
    coordinates when ``df`` has ``<q>_hat`` columns, evaluated with the engine model that θ̂
    was calibrated with (``effects``: :func:`.baseline.health_effects` of the table's
    metadata; none: the model as designed)."""
    hi = None
    if any(q + "_hat" in df.columns for q in THETA_NAMES):
        from .baseline import engine_health_index

        hi = engine_health_index(effects)
    return flight_table(df, hi, source=source)


def rows_for(config: TrainConfig, frame: pd.DataFrame, effects: Sequence[str],
             source: str = "table") -> pd.DataFrame:
    """The rows a model of ``config`` reads from the sorted table ``frame``: its flight table
    when :attr:`TrainConfig.reads_flights` (a sample model asking for health coordinates
    needs one row per cycle, where the flight table has the same rows), else ``frame``."""
    if not config.reads_flights:
        return frame
    if not config.per_flight and not one_per_cycle(frame):
        groups = ", ".join(health_groups_of(config.inputs))
        raise InputError(f"{source}: inputs {config.inputs!r} name {groups}, computed per "
                         f"flight; the model {config.model} reads samples, and the table has "
                         "several rows per cycle (use the flight models tcn, trend or similarity)")
    return flight_frame(frame, source, effects)


@dataclass
class DevelopmentRows:
    """The rows a model of a configuration learns from (:func:`development_rows`)."""

    config: TrainConfig  # resolved
    frame: pd.DataFrame  # the development units' rows (or flight table), sorted
    columns: list[str]
    dev_units: list[int]
    test_units: list[int]
    health_effects: tuple[str, ...]


def development_rows(df: pd.DataFrame, metadata: dict | None, config: TrainConfig,
                     source: str = "table") -> DevelopmentRows:
    """Step 1 of the module docstring, shared by the networks (:func:`prepare`) and the
    similarity library (:func:`.ensemble.fit_library`): the development and test units, the
    rows the model reads (:func:`rows_for`), its input columns, checked; a window longer
    than every development unit and validation or conformal units among the test units are
    refused."""
    cfg = config.resolved()
    if TARGET not in df.columns:
        raise InputError(f"{source}: no {TARGET} column to train on")
    present = np.unique(df["unit"].to_numpy()).tolist()
    dev, test = development_and_test_units(present, metadata, cfg.units, cfg.test_units, source)
    every_unit = set(present) <= set(dev)  # no copy of the table when it is all development
    frame = sort_table(df if every_unit else df[df["unit"].isin(dev)])
    effects = tuple(health_effects(metadata))
    frame = rows_for(cfg, frame, effects, source)
    columns = resolve_inputs(cfg.inputs, list(frame.columns), source,
                             unobservable_columns(frame))
    check_table(frame, columns, source)
    unit = frame["unit"].to_numpy()
    longest = int(np.bincount(np.unique(unit, return_inverse=True)[1]).max())
    if cfg.window > longest:
        rows = "flights" if cfg.per_flight else "rows"
        raise InputError(f"{source}: window {cfg.window} is longer than the longest development "
                         f"unit ({longest} {rows})")
    for what, given in (("validation", cfg.val_units or ()),
                        ("conformal", cfg.conformal_units)):
        held = sorted(set(int(u) for u in given) & set(test))
        if held:
            raise InputError(f"{source}: {what} unit(s) {', '.join(map(str, held))} are test "
                             "units (a test unit is only ever evaluated; choose development "
                             f"units: {', '.join(map(str, sorted(dev)))})")
    return DevelopmentRows(cfg, frame, columns, dev, test, effects)


def prepare(df: pd.DataFrame, metadata: dict | None, config: TrainConfig,
            source: str = "table") -> Prepared:
    """Steps 1-3 of the module docstring."""
    d = development_rows(df, metadata, config, source)
    cfg, frame, columns, dev, test, effects = (d.config, d.frame, d.columns, d.dev_units,
                                               d.test_units, d.health_effects)
    unit = frame["unit"].to_numpy()
    cycle = frame["cycle"].to_numpy()
    n_fit = len(set(dev) - set(cfg.conformal_units))
    cfg = replace(cfg, validation=cfg.validation_for(n_fit))
    roles = assign_roles(unit, cycle, dev, (), seed=cfg.seed,
                         val_fraction=cfg.val_fraction, validation=cfg.validation,
                         val_units=cfg.val_units, conformal_units=cfg.conformal_units,
                         source=source)
    conditions = training_conditions(frame, roles == TRAIN)
    if cfg.normalise == "auto":
        cfg = replace(cfg, normalise="condition" if len(conditions) > 1 else "minmax")
    scaler = fit_scaler(cfg.normalise, frame, columns, roles == TRAIN, source)
    dropped: list[str] = []
    if cfg.drop_constant:
        dropped = [c for c, k in zip(columns, scaler.constant, strict=True) if k]
        if len(conditions) == 1:  # the settings are noise around the one condition
            dropped += [c for c in columns if c in W_NAMES and c not in dropped]
        if len(dropped) == len(columns):
            raise InputError(f"{source}: every input column is constant over the training "
                             f"rows, or a setting of their single operating condition "
                             f"({', '.join(columns)})")
        columns = [c for c in columns if c not in set(dropped)]
        scaler = scaler.subset(columns)
    x = scaler.transform_frame(frame, source=source)
    y = frame[TARGET].to_numpy(np.float64)
    if cfg.max_rul is not None:
        y = np.minimum(y, cfg.max_rul)
    offset = None
    if cfg.model == "trend":
        if cfg.trend_cap is None:
            cfg = replace(cfg, trend_cap=float(unit_lives(frame[roles == TRAIN]).max()))
        offset = trend_per_flight(frame, cfg.trend_cap, source)
        y = y - offset
    windows = {}
    if cfg.per_flight:
        # a flight model reads a unit's whole history, as it does at prediction: windows
        # over whole units, each taking the role of its last flight (validation flights
        # inside a training unit stay in the history of the windows after them)
        used = np.isin(roles, (TRAIN, VALIDATION, CONFORMAL))
        a, b = segments(unit, used)
        every = make_windows(x, a[used[a]], b[used[a]], cfg.window, cfg.stride, y,
                             pad_all=True)
        for role in (TRAIN, VALIDATION, CONFORMAL):
            pick = roles[every.rows] == role
            if pick.any():
                windows[role] = every.subset(pick)
    else:
        a, b = segments(unit, roles)
        seg_role = roles[a]
        for role in (TRAIN, VALIDATION, CONFORMAL):
            pick = seg_role == role
            if pick.any():
                windows[role] = make_windows(x, a[pick], b[pick], cfg.window, cfg.stride, y)
    train = windows.get(TRAIN)
    cfg = cfg.sized(0 if train is None else len(train), n_fit)
    keep = [c for c in ("unit", "cycle", "t", TARGET) if c in frame.columns]
    return Prepared(cfg, columns, scaler, frame[keep], roles, windows, dev, test, dropped,
                    offset, effects if cfg.reads_flights else ())


def training_conditions(frame: pd.DataFrame, rows: np.ndarray) -> tuple[int, ...]:
    """The distinct operating conditions of the training ``rows`` when the table labels every
    one of them (its ``condition`` column, as ``import-cmapss`` writes it, with no 0 = "none
    matched"); ``()`` otherwise.

    Several: ``normalise="auto"`` standardises per condition. Exactly one: the operating
    settings are that condition plus measurement noise (C-MAPSS FD001: altitude about
    ±0.009 kft, Mach about ±0.0006 around sea-level static), inputs that carry nothing but
    noise, so ``drop_constant`` drops them with the constant columns (the published FD001 /
    FD003 models use the sensors only)."""
    if CONDITION not in frame.columns:
        return ()
    cond = frame[CONDITION].to_numpy()[rows]
    if cond.size == 0 or np.any(cond == 0):
        return ()
    return tuple(int(k) for k in np.unique(cond))


def predict_windows(net: nn.Module, windows: Windows, device: torch.device,
                    batch: int = EVAL_BATCH,
                    progress: Callable[[int], None] | None = None) -> np.ndarray:
    """Network outputs on every window, float64 (n,); ``progress(k)`` after each batch of
    ``k`` windows."""
    net.eval()
    out = []
    with torch.no_grad():
        for i in range(0, len(windows), batch):
            idx = torch.arange(i, min(i + batch, len(windows)))
            out.append(net(windows.batch(idx).to(device)).double().cpu())
            if progress is not None:
                progress(len(idx))
    return torch.cat(out).numpy() if out else np.zeros(0)


def _mse(net: nn.Module, windows: Windows, device: torch.device) -> float:
    pred = predict_windows(net, windows, device)
    d = pred - windows.target.double().numpy()
    return float(np.mean(d * d))


EpochCallback = Callable[[int, int, float, float | None], None]
BatchCallback = Callable[[int, int, float], None]


def train_member(prep: Prepared, seed: int, device: torch.device,
                 on_batch: BatchCallback | None = None,
                 on_epoch: EpochCallback | None = None) -> Member:
    """Train one network from ``seed`` (module docstring, step 4)."""
    cfg = prep.config
    train = prep.windows.get(TRAIN)
    if train is None or len(train) == 0:
        raise InputError("no training windows (every training row is validation?)")
    val = prep.windows.get(VALIDATION)
    forked = torch.random.fork_rng(devices=[device] if device.type == "cuda" else [])
    with deterministic(device), forked:  # the caller's global RNG state is restored after
        torch.manual_seed(int(seed) + 2)  # dropout masks (module docstring)
        net = build_model(cfg.model, len(prep.columns), cfg.window, seed=seed).to(device)
        opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, amsgrad=True)
        plateau = None if cfg.schedule == "constant" else \
            torch.optim.lr_scheduler.ReduceLROnPlateau(
                opt, mode="min", factor=PLATEAU_FACTOR, patience=max(1, cfg.patience // 2),
                min_lr=cfg.lr * PLATEAU_FLOOR)
        order = torch.Generator().manual_seed(int(seed) + 1)
        tw = train.to(device)
        n = len(tw)
        best, best_state, best_epoch, bad = float("inf"), None, 0, 0
        history = []
        for epoch in range(1, cfg.epochs + 1):
            t0 = time.perf_counter()
            net.train()
            perm = torch.randperm(n, generator=order).to(device)
            total = 0.0
            for i in range(0, n, cfg.batch_size):
                idx = perm[i:i + cfg.batch_size]
                xb, yb = tw.batch(idx), tw.target[idx]
                opt.zero_grad(set_to_none=True)
                loss = torch.mean((net(xb) - yb) ** 2)
                loss.backward()
                opt.step()
                total += float(loss.detach()) * len(idx)
                if on_batch is not None:
                    on_batch(epoch, min(i + cfg.batch_size, n), total / min(i + cfg.batch_size, n))
            train_loss = total / n
            val_loss = _mse(net, val, device) if val is not None and len(val) else None
            history.append({"epoch": epoch, "train_loss": train_loss, "val_loss": val_loss,
                            "lr": float(opt.param_groups[0]["lr"]),
                            "seconds": time.perf_counter() - t0})
            if on_epoch is not None:
                on_epoch(epoch, cfg.epochs, train_loss, val_loss)
            score = train_loss if val_loss is None else val_loss
            if plateau is not None:
                plateau.step(score)
            if score < best:
                best, best_epoch, bad = score, epoch, 0
                best_state = copy.deepcopy(net.state_dict())
            else:
                bad += 1
                if val_loss is not None and bad >= cfg.patience:
                    break
        if best_state is None:  # every epoch's loss inf or NaN
            raise InputError(f"training diverged (seed {seed}): the "
                             f"{'validation' if val is not None and len(val) else 'training'}"
                             f" loss was not finite in any of {len(history)} epochs; lower "
                             f"--lr (now {cfg.lr:g})")
        net.load_state_dict(best_state)
    state = {k: v.detach().cpu().clone() for k, v in net.state_dict().items()}
    return Member(int(seed), state, history, best_epoch, parameter_count(net))


def _console():
    from rich.console import Console

    return Console(stderr=True, highlight=False)


@contextmanager
def progress_bar(n_windows: int, label: str, quiet: bool) -> Iterator[tuple]:
    """``(on_batch, on_epoch)`` callbacks drawing one bar per epoch, or ``(None, None)``."""
    if quiet:
        yield None, None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    prog = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TextColumn("{task.fields[loss]}"), TimeElapsedColumn(), console=_console())
    state = {"task": None, "epoch": 0, "val": None}

    def on_batch(epoch, done, loss):
        if state["epoch"] != epoch:
            state["epoch"] = epoch
            state["task"] = prog.add_task(f"{label} epoch {epoch}", total=n_windows, loss="")
        val = "" if state["val"] is None else f" val {state['val']:.4g}"
        prog.update(state["task"], completed=done, loss=f"train {loss:.4g}{val}")

    def on_epoch(epoch, epochs, train_loss, val_loss):
        state["val"] = val_loss
        val = "" if val_loss is None else f"  val {val_loss:.4g}"
        prog.update(state["task"], loss=f"train {train_loss:.4g}{val}")

    with prog:
        yield on_batch, on_epoch
