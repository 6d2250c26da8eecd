"""Figures of the prognostics experiments (matplotlib, Agg backend, PNG, written atomically).

- :func:`plot_rul`: per test unit, the true RUL against cycles, the per-cycle mean prediction,
  its min/max band over the cycle's samples (the paper's Fig. 7 shading) and, when present,
  the conformal interval; the ±5-cycle corridor of the prediction horizon is dashed.
- :func:`plot_theta`: per-cycle mean θ̂ of every unit (true θ dashed when the table has it).
- :func:`plot_training_curves`: training and validation loss per epoch.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np
import pandas as pd

from engine_model.runtime.atomic import atomic_output
from engine_model.runtime.ownership import OWNED_FILE

from .metrics import HORIZON_TOL


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path) -> None:
    with atomic_output(path, OWNED_FILE) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")


def plot_rul(per_cycle: pd.DataFrame, title: str, path: str | os.PathLike) -> None:
    """``per_cycle``: :func:`metrics.per_cycle` output (``unit``, ``cycle``, ``RUL``, ``mean``,
    ``min``, ``max`` and optionally ``lower``, ``upper``)."""
    plt = _pyplot()
    units = sorted(per_cycle["unit"].unique())
    fig, axes = plt.subplots(1, len(units), figsize=(4.2 * len(units), 3.6), squeeze=False)
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
        ax.set_xlabel("cycle")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("RUL [cycles]")
    axes[0][0].legend(fontsize=7)
    fig.suptitle(title)
    _save(fig, path)
    plt.close(fig)


def plot_theta(theta: pd.DataFrame, columns, path: str | os.PathLike,
               truth: pd.DataFrame | None = None) -> None:
    """Per-cycle θ̂ (``unit``, ``cycle``, ``columns``); ``truth`` with the same layout dashed."""
    plt = _pyplot()
    columns = list(columns)
    fig, axes = plt.subplots(1, len(columns), figsize=(4.2 * len(columns), 3.4),
                             squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, col in zip(axes[0], columns, strict=True):
        for i, (u, g) in enumerate(theta.groupby("unit")):
            colour = colours[i % len(colours)]
            ax.plot(g["cycle"], g[col], "-", color=colour, lw=1.2, label=f"unit {u}")
            if truth is not None and col in truth.columns:
                t = truth[truth["unit"] == u]
                ax.plot(t["cycle"], t[col], "--", color=colour, lw=0.8)
        ax.set_title(col + ("  (dashed: truth)" if truth is not None else ""), fontsize=9)
        ax.set_xlabel("cycle")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=6, ncol=2)
    _save(fig, path)
    plt.close(fig)


def plot_training_curves(histories: Mapping[str, list], path: str | os.PathLike) -> None:
    """``histories``: label -> list of ``{"epoch", "train_loss", "val_loss"}``."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
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
