"""Figures of the prognostics experiments (matplotlib, Agg backend, PNG, written atomically).

- :func:`plot_rul`: per test unit, the true RUL against cycles, the per-cycle mean prediction,
  its min/max band over the cycle's samples (the paper's Fig. 7 shading) and, when present,
  the conformal interval; the ±5-cycle corridor of the prediction horizon is dashed.
- :func:`plot_theta`: per-cycle mean θ̂ of every unit with its ±1.96 σ band (true θ dashed
  when the table has it).
- :func:`plot_error_by_rul`: box plots of the error against true RUL
  (:func:`metrics.error_by_rul`), one box per bin and input set.
- :func:`plot_training_curves`: training and validation loss per epoch.

Every figure is written at :data:`DPI` dots per inch, sized to be read at 1280 px across, with
its axes labelled with units; cycles are whole numbers on the axes.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np
import pandas as pd

from engine_model.runtime.atomic import atomic_output
from engine_model.runtime.ownership import OWNED_FILE

from .metrics import HORIZON_TOL

DPI = 150


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path) -> None:
    with atomic_output(path, OWNED_FILE) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI)  # every figure lays itself out (constrained)


def _whole_cycles(ax) -> None:
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))


def plot_rul(per_cycle: pd.DataFrame, title: str, path: str | os.PathLike) -> None:
    """``per_cycle``: :func:`metrics.per_cycle` output (``unit``, ``cycle``, ``RUL``, ``mean``,
    ``min``, ``max`` and optionally ``lower``, ``upper``)."""
    plt = _pyplot()
    units = sorted(per_cycle["unit"].unique())
    fig, axes = plt.subplots(1, len(units), figsize=(max(4.6 * len(units), 8.5), 4.2),
                             squeeze=False, layout="constrained")
    for ax, u in zip(axes[0], units, strict=True):
        g = per_cycle[per_cycle["unit"] == u]
        c = g["cycle"].to_numpy()
        if "lower" in g.columns:
            ax.fill_between(c, g["lower"], g["upper"], color="tab:orange", alpha=0.18,
                            label="conformal interval")
        ax.fill_between(c, g["min"], g["max"], color="tab:blue", alpha=0.25,
                        label="min-max in cycle")
        ax.plot(c, g["mean"], "o-", color="tab:blue", ms=3, label="mean prediction")
        ax.plot(c, g["RUL"], "k-", lw=1.2, label="true RUL")
        ax.plot(c, g["RUL"] + HORIZON_TOL, "r--", lw=0.7, label=f"±{HORIZON_TOL:g} cycles")
        ax.plot(c, g["RUL"] - HORIZON_TOL, "r--", lw=0.7)
        ax.set_title(f"unit {u}")
        ax.set_xlabel("flight cycle")
        _whole_cycles(ax)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("RUL [cycles]")
    axes[0][0].legend(fontsize=7)
    fig.suptitle(title)
    _save(fig, path)
    plt.close(fig)


def plot_theta(theta: pd.DataFrame, columns, path: str | os.PathLike,
               truth: pd.DataFrame | None = None, std: pd.DataFrame | None = None) -> None:
    """Per-cycle θ̂ (``unit``, ``cycle``, ``columns``), one panel per parameter; ``std``, the
    same layout with each estimate's standard deviation, draws the band θ̂ ± 1.96 σ; ``truth``,
    the same layout, dashed. θ is a fractional change of a component's efficiency or flow
    (-0.01: 1 % below its map), so the y axes are in %."""
    plt = _pyplot()
    columns = list(columns)
    fig, axes = plt.subplots(1, len(columns), figsize=(4.6 * len(columns), 3.8),
                             squeeze=False, layout="constrained")
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, col in zip(axes[0], columns, strict=True):
        for i, (u, g) in enumerate(theta.groupby("unit")):
            colour = colours[i % len(colours)]
            c = g["cycle"].to_numpy()
            est = 100.0 * g[col].to_numpy(float)
            if std is not None and col in std.columns:
                sd = 100.0 * std.loc[std["unit"] == u, col].to_numpy(float)
                ax.fill_between(c, est - 1.96 * sd, est + 1.96 * sd, color=colour, alpha=0.15,
                                lw=0)
            ax.plot(c, est, "-", color=colour, lw=1.2, label=f"unit {u}")
            if truth is not None and col in truth.columns:
                t = truth[truth["unit"] == u]
                ax.plot(t["cycle"], 100.0 * t[col], "--", color=colour, lw=0.8)
        ax.set_title(col.removesuffix("_hat"), fontsize=10)
        ax.set_xlabel("flight cycle")
        ax.set_ylabel(f"θ̂ {col.removesuffix('_hat')} [% change]")
        _whole_cycles(ax)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7, ncol=2)
    what = ["solid: θ̂ (per-cycle mean)"]
    if std is not None:
        what.append("band: ± 1.96 σ")
    if truth is not None:
        what.append("dashed: true θ")
    fig.suptitle("; ".join(what), fontsize=10)
    _save(fig, path)
    plt.close(fig)


def plot_error_by_rul(errors: Mapping[str, list], path: str | os.PathLike) -> None:
    """``errors``: label -> :func:`metrics.error_by_rul` bins. One box per bin and label:
    median, quartiles, whiskers at the 5 and 95 % quantiles, of ``Δ = true - predicted``."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.2), layout="constrained")
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    labels = list(errors)
    bins = sorted({(b["lo"], b["hi"]) for v in errors.values() for b in v})
    width = 0.8 / max(len(labels), 1)
    for i, label in enumerate(labels):
        by = {(b["lo"], b["hi"]): b for b in errors[label]}
        stats, pos = [], []
        for k, key in enumerate(bins):
            if key in by:
                b = by[key]
                stats.append({"med": b["median"], "q1": b["q25"], "q3": b["q75"],
                              "whislo": b["q05"], "whishi": b["q95"], "fliers": []})
                pos.append(k + (i - (len(labels) - 1) / 2) * width)
        art = ax.bxp(stats, positions=pos, widths=width * 0.9, patch_artist=True,
                     showfliers=False, medianprops={"color": "k"})
        for box in art["boxes"]:
            box.set(facecolor=colours[i % len(colours)], alpha=0.5)
        ax.plot([], [], "s", color=colours[i % len(colours)], alpha=0.5, label=label)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xticks(range(len(bins)), [f"{lo:g}-{hi:g}" for lo, hi in bins])
    ax.set_xlabel("true RUL [cycles]")
    ax.set_ylabel("Δ = true - predicted [cycles]  (> 0: early)")
    ax.grid(alpha=0.3, axis="y")
    ax.legend(fontsize=8)
    _save(fig, path)
    plt.close(fig)


def plot_training_curves(histories: Mapping[str, list], path: str | os.PathLike) -> None:
    """``histories``: label -> list of ``{"epoch", "train_loss", "val_loss"}``."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.5), layout="constrained")
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for i, (label, h) in enumerate(histories.items()):
        colour = colours[i % len(colours)]
        ep = np.array([r["epoch"] for r in h])
        ax.semilogy(ep, [r["train_loss"] for r in h], "-", color=colour, label=f"{label} train")
        val = [np.nan if r["val_loss"] is None else r["val_loss"] for r in h]
        ax.semilogy(ep, val, "--", color=colour, label=f"{label} val")
    ax.set_xlabel("epoch")
    ax.set_ylabel("MSE [cycles²]")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    _save(fig, path)
    plt.close(fig)
