"""The before/after report of :func:`loop.discover`: ``discover.json``, ``discover.md`` and
``residuals.png`` in one output directory, written atomically
(:mod:`engine_model.runtime.atomic`: a hidden temporary sibling moved into place; the
temporaries a killed writer left are removed by the next one). An existing directory is
replaced by the ownership rule (:mod:`engine_model.runtime.ownership`, kind
:data:`REPORT_DIRECTORY`): an earlier report, recognised by its ``discover.json``, holding
nothing but the report's three files; anything else only with ``--overwrite``; never what the
command reads.

The PNG shows, for each added effect (or, when something unknown remains, for the channel with
the most structure), the whitened residual of the channel it changed most against the
operating variable that residual follows most closely, before (the first null fit) and after
(the final model), with bin means.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from engine_model.datasets.jsonable import jsonable
from engine_model.runtime.atomic import atomic_output
from engine_model.runtime.ownership import OutputKind, check_output

from .unknown import BASIS_NAMES, basis

REPORT_JSON = "discover.json"
REPORT_FILES = (REPORT_JSON, "discover.md", "residuals.png")
DRIVERS = ("alt", "Mach", "TRA", "T2", "t_flight", "cycle")


def report_dict(d) -> dict:
    return jsonable(d.to_dict())


def _fmt(v, nd=3):
    if v is None:
        return "-"
    if isinstance(v, float):
        return f"{v:.{nd}g}"
    return str(v)


def _p(p) -> str:
    return "< 1e-300" if p == 0 else _fmt(p)


def markdown(d) -> str:
    r = report_dict(d)
    dg = r["diagnostics"]
    lines = [f"# hyprog discover: {r['verdict']}", "",
             f"{dg['samples']:,} samples of {len(dg['units'])} unit(s), sensors "
             f"{', '.join(dg['sensors'])}; theta {', '.join(dg['params'])}; warm start "
             f"{dg['method']}; family-wise alpha {dg['alpha']}; {dg['seconds']:.1f} s.", ""]
    dr = r["drift"]
    lines += [f"Drift of theta: q = {dr['q']:.3g} per sqrt(hour) ({dr['method']}).", ""]
    ns = r["noise"]
    flagged = [k for k, v in ns.get("channels", {}).items() if v["flagged"]]
    if ns.get("note"):
        lines += [f"Noise model: not checked ({ns['note']}); the documented sensor noise is "
                  "used.", ""]
    elif ns.get("checked"):
        lines += ["Noise model: " + (", ".join(
            f"{k} x{ns['channels'][k]['std_ratio']:.2f}" for k in flagged) + " rescaled"
            if flagged else "consistent with the documented sensor noise on every channel")
            + ".", ""]
    if r["found"]:
        lines += ["## Effects added", "", "| # | effect | parameters (95 % interval) | LR "
                  "| p | share of excess | held-out SSE without -> with |", "|---|---|---|---|"
                  "---|---|---|"]
        for k, f in enumerate(r["found"], 1):
            ps = "; ".join(f"{q} = {_fmt(v, 4)} ± {_fmt(f['std'][q], 2)} "
                           f"[{_fmt(f['ci95'][q][0], 3)}, {_fmt(f['ci95'][q][1], 3)}]"
                           for q, v in f["params"].items())
            ho = f["held_out_sse"]
            lines.append(f"| {k} | {f['name']} | {ps} | {_fmt(f['likelihood_ratio'])} | "
                         f"{_p(f['p_value'])} | {_fmt(f['explained_share'], 2)} | "
                         f"{_fmt(ho['without'], 5)} -> {_fmt(ho['with'], 5)} |")
        lines.append("")
    for a in r["ambiguous"]:
        lines += [f"**Ambiguous: {a['candidates'][0]} or {a['candidates'][1]}** (projected "
                  f"signatures correlated {a['correlation']:.3f}, log-likelihoods differ by "
                  f"{abs(a['loglik_difference']):.2f}). Operating points that separate them:"]
        for p in a["separating_points"]:
            lines.append(f"- alt {p['alt_ft'][0]:.0f}-{p['alt_ft'][1]:.0f} ft, Mach "
                         f"{p['Mach'][0]}-{p['Mach'][1]}, TRA {p['TRA'][0]:.0f}-"
                         f"{p['TRA'][1]:.0f} % ({100 * p['share']:.0f} % of the difference)")
        lines.append("")
    if r["unknown"]:
        lines += ["## Unknown effect", "", "Structure that no candidate explains, by channel "
                  "(sparse regression of the residual on the operating variables):", ""]
        for ch in r["unknown"]["channels"]:
            h = r["unknown"]["hint"][ch]
            terms = ", ".join(f"{t} ({c:+.2f})" for t, c in zip(h["terms"], h["coefficients"],
                                                             strict=True)) or "(bias / "\
                "correlation only)"
            lines.append(f"- {ch} (residual RMSE {h['rmse']:.3g} noise std): {terms}; "
                         f"explains {100 * h['explained']:.0f} % of its residual variance")
        lines.append("")
    if r["rejected"]:
        lines += ["Candidates screened significant but not added:", ""]
        lines += [f"- {x['name']}: {x['reason']}" for x in r["rejected"]]
        lines.append("")
    b, a = r["before"], r["after"]
    lines += ["## Residual before and after", "", f"On {b['on']}; whitened (noise units): "
              f"chi^2 per degree of freedom {_fmt(b['chi2_per_dof'])} -> "
              f"{_fmt(a['chi2_per_dof'])}.", "",
              "| channel | RMSE before | RMSE after | bias before | bias after | lag-1 before "
              "| lag-1 after |", "|---|---|---|---|---|---|---|"]
    for ch in b["channels"]:
        x, y = b["channels"][ch], a["channels"][ch]
        lines.append(f"| {ch} | {_fmt(x['rmse'])} | {_fmt(y['rmse'])} | {_fmt(x['bias'])} | "
                     f"{_fmt(y['bias'])} | {_fmt(x['lag1'])} | {_fmt(y['lag1'])} |")
    lines.append("")
    if r["theta_error"]:
        lines += ["## theta_hat against the truth (per cycle)", "",
                  "| parameter | bias before | bias after | RMSE before | RMSE after |",
                  "|---|---|---|---|---|"]
        for q, x in r["theta_error"]["before"].items():
            y = r["theta_error"]["after"][q]
            lines.append(f"| {q} | {x['bias']:.2e} | {y['bias']:.2e} | {x['rmse']:.2e} | "
                         f"{y['rmse']:.2e} |")
        lines.append("")
    last = r["screens"][-1] if r["screens"] else None
    if last:
        lines += [f"## Last screen (iteration {last['iteration']}, family-wise critical p = "
                  f"{last['p_crit']:.2e})", "", "| candidate | statistic | df | p | projected"
                  " / whole signature | min. detectable size |", "|---|---|---|---|---|---|"]
        for c in last["candidates"][:12]:
            md = ", ".join(f"{q} {_fmt(v, 2)}" for q, v in zip(c["params"],
                                                                c["min_detectable"],
                                                                strict=True))
            rt = ", ".join(_fmt(v, 2) for v in c["ratio"])
            lines.append(f"| {c['name']}{' (absorbed by theta)' if c['absorbed'] else ''} | "
                         f"{_fmt(c['statistic'])} | {c['df']} | {_p(c['p_value'])} | {rt} | "
                         f"{md} |")
        lines.append("")
    lines.append("Figure: residuals.png (every channel's residual against the variable it "
                 "follows most, before and after).")
    return "\n".join(lines) + "\n"


def _panels(d) -> list[tuple[str, str]]:
    """(channel, title) per panel: each added effect's most reduced channel, else the channel
    with the most unexplained structure, else the worst channel."""
    out = []
    for f in d.found:
        drop = {c: f["residual_before"][c] - f["residual_after"][c] for c in f["residual_before"]}
        out.append((max(drop, key=drop.get), f"added {f['name']}"))
    if d.unknown:
        hint = d.unknown["hint"]
        ch = max(hint, key=lambda c: hint[c]["explained"])
        out.append((ch, "unknown effect"))
    if not out:
        ch = max(d.before["channels"], key=lambda c: d.before["channels"][c]["rmse"] or 0.0)
        out.append((ch, "largest residual"))
    return out[:4]


#: Each driver's axis: the factor from :func:`.unknown.basis`'s scaled column back to its
#: physical unit, and the label.
DRIVER_AXES = {"alt": (1e4, "altitude [ft]"), "Mach": (1.0, "Mach [-]"),
               "TRA": (1.0, "throttle TRA [%]"), "T2": (100.0, "T2 [°R]"),
               "t_flight": (1.0, "time since take-off [h]"), "cycle": (1.0, "flight cycle")}
N_BINS = 12


def _binned(x: np.ndarray, e: np.ndarray, edges: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per bin of ``x``: its centre, the mean of ``e`` and its 5 / 95 % quantiles (NaN in an
    empty bin)."""
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    stats = np.full((len(edges) - 1, 3), np.nan)
    for i in range(len(edges) - 1):
        v = e[idx == i]
        if v.size:
            stats[i] = v.mean(), *np.quantile(v, [0.05, 0.95])
    return 0.5 * (edges[1:] + edges[:-1]), stats[:, 0], stats[:, 1], stats[:, 2]


def plot(d, path: Path) -> None:
    """Every sensor channel's whitened residual (in noise std) against the driving variable it
    follows most (of :data:`DRIVERS`, by correlation before), before and after: per bin of
    that variable the mean (line) and the 5-95 % range (band), so that neither hides the
    other. A channel named by the findings (:func:`_panels`) has it in its title."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    problem, before, after = d.plots["problem"], d.plots["before"], d.plots["after"]
    sensors = list(problem.sensors)
    roles = dict(_panels(d))
    X = np.vstack([basis(u.series.w, u.frame["t"].to_numpy(float) if "t" in u.frame else None,
                         u.cyc, u.cycle) for u in problem.units])
    ok = np.concatenate([a & b for a, b in zip(before.lin.ok, after.lin.ok, strict=True)])
    eb = np.vstack(before.lin.e)[ok]
    ea = np.vstack(after.lin.e)[ok]
    X = X[ok]
    ncols = min(4, len(sensors))
    nrows = -(-len(sensors) // ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(4.0 * ncols, 3.0 * nrows), squeeze=False,
                             layout="constrained")
    cols = [BASIS_NAMES.index(v) for v in DRIVERS]
    for k, ax in enumerate(axes.flat):
        if k >= len(sensors):
            ax.set_visible(False)
            continue
        ch = sensors[k]
        corr = [abs(np.corrcoef(X[:, c], eb[:, k])[0, 1]) if X[:, c].std() > 0 else 0.0
                for c in cols]
        name = DRIVERS[int(np.nanargmax(corr))]
        factor, label = DRIVER_AXES[name]
        xv = X[:, BASIS_NAMES.index(name)] * factor
        edges = np.unique(np.quantile(xv, np.linspace(0, 1, N_BINS + 1)))
        if len(edges) < 2:
            edges = np.array([xv.min() - 0.5, xv.max() + 0.5])
        for e, colour, what in ((eb[:, k], "0.35", "before"), (ea[:, k], "tab:blue", "after")):
            mid, mean, lo, hi = _binned(xv, e, edges)
            ax.fill_between(mid, lo, hi, color=colour, alpha=0.2, lw=0)
            ax.plot(mid, mean, "o-", color=colour, ms=3, lw=1.6,
                    label=f"{what}: bin mean, 5-95 %")
        ax.axhline(0, color="k", lw=0.5)
        ax.set_xlabel(label)
        ax.set_ylabel("residual [noise std]")
        ax.set_title(ch + (f": {roles[ch]}" if ch in roles else ""), fontsize=10)
        ax.grid(alpha=0.3)
    axes.flat[0].legend(loc="best", fontsize=7)
    fig.suptitle("whitened residuals before and after the added effects" if d.found else
                 "whitened residuals (no effect added: after = before)")
    fig.savefig(path, dpi=150)
    plt.close(fig)


def is_report(path: Path) -> bool:
    """``path`` is an earlier report (a directory with ``discover.json``)."""
    return (path / REPORT_JSON).is_file()


#: A discover report (the ownership rule's kind, module docstring).
REPORT_DIRECTORY = OutputKind("an earlier discover report", directory=True, ours=is_report,
                              layout=lambda path: REPORT_FILES)


def check_report_target(out: str | Path, overwrite: bool = False, inputs=()) -> Path:
    """``out`` may receive a report (module docstring; ``inputs``: what the command reads).
    Call it before the discovery run so that a bad ``--out`` fails first, not after
    minutes."""
    return check_output(out, REPORT_DIRECTORY, overwrite, inputs)


def write_report(d, out: str | Path, overwrite: bool = False, inputs=()) -> Path:
    """Write ``discover.json``, ``discover.md`` and ``residuals.png`` into ``out``, atomically
    (module docstring)."""
    with atomic_output(out, REPORT_DIRECTORY, overwrite, inputs) as tmp:
        (tmp / REPORT_JSON).write_text(json.dumps(report_dict(d), indent=2, allow_nan=False))
        (tmp / "discover.md").write_text(markdown(d))
        plot(d, tmp / "residuals.png")
    return Path(out)
