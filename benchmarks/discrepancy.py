"""The discrepancy loop (:mod:`calibration.discrepancy`) on fleets with an undeclared effect:
detection, identification, false discoveries, residual reduction, theta_hat bias before and
after.

    python benchmarks/discrepancy.py                         # every effect at its typical size
    python benchmarks/discrepancy.py --sizes 0.5,1,3 --seeds 0,1,2 --null-fleets 20
    python benchmarks/discrepancy.py --effects customer_bleed,hp_offtake --units 1,2
    python benchmarks/discrepancy.py --sizes 0.1,0.3,1,3 --seeds 0,1,2,3,4 \\
        --null-fleets 800 --results benchmarks/results      # the committed 940-run table

Resumable: every run is appended to ``--runs`` (JSON lines) as soon as it ends, keyed by
(effect, size, seed, unit, method); a rerun with the same file skips the runs already there,
so an interrupted benchmark continues where it stopped. The table (``--table``, Markdown) and
the JSON of the runs asked for (``--out``) are written at the end from the cached runs.
``--runs`` and ``--table`` default to ``discrepancy_runs.jsonl.gz`` and
``discrepancy_table.md`` in ``--results``, itself ``out/discrepancy`` unless named: the
committed files (``--results benchmarks/results``) are read and written only when asked.

Sizes are multiples of each effect's documented realistic size (``Param.typical``; the T48
sensor offset: +6 degR, about 1.5 sigma of the channel at cruise). Steady effects are switched
on in the truth model (the candidate model's variant, same compiled code); sensor effects
(bias, drift on T48) are applied to the noise-free readings through the effect's own ``apply``
before the simulator's noise, which is what the simulator does with a sensor effect in the
truth. Fleets: units of the ``tiny`` preset (one per run by default). Each run is one
:func:`discover` call (warm start ``coarse`` unless ``--method``, q by maximum likelihood,
alpha 0.01).

``--mds-units``: sizes are multiples of each effect's **minimum detectable size** (MDS) instead:
the size of its scaled parameter that the loop's first screen detects with 80 % power at the
family-wise level (:func:`calibration.discrepancy.identifiability.candidate_report`), the
median over ``--mds-fleets`` no-effect reference fleets (runs keyed ``mds_reference``,
cached like the others). Sizes 0.5, 1, 2 are then below, at and above it; the detection rate
at 1 x MDS checks the MDS itself (about 80 % expected). Every run records the MDS of every
candidate on its own data (``mds``), and the table shows each size in both units when the
reference is known.

Reported per effect and size: detection rate (anything added or an unknown effect),
identification rate (the true effect added first), residual RMSE of the most affected channel
before -> after (held-out flights, noise units), theta_hat bias before -> after (largest over
the estimated parameters). Null fleets: the rate of runs that add any effect (target <= alpha)
and of runs that report an unknown effect.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))
from run_cache import append_run, read_runs  # noqa: E402

# (the project's modules and scipy are imported where they are used: ``--help`` answers at
# once)

#: where the runs and tables go unless ``--results`` names another folder
OUT = ROOT / "out" / "discrepancy"

# effect -> (spec at size 1, the parameter that scales)
EFFECTS = {
    "customer_bleed": ("customer_bleed:f0={x}", 0.015),
    "hp_offtake": ("hp_offtake:P_kw={x}", 150.0),
    "reynolds": ("reynolds:n={x}", 0.05),
    "inlet_loss": ("inlet_loss:dp={x}", 0.005),
    "nozzle_area": ("nozzle_area:dA8={x}", 0.02),
    "sensor_bias_T48": ("sensor_bias:channel=T48,offset={x}", 6.0),
    "sensor_drift_T48": ("sensor_drift:channel=T48,rate={x}", 1e-4),
}


def simulate(base, name: str, size: float, unit: int, seed: int):
    from calibration.discrepancy.synthetic import unit_with_effect

    spec, typical = EFFECTS[name]
    return unit_with_effect(base, spec.format(x=size * typical), unit, seed)


def one_run(base, frames, opts, truth_name=None) -> dict:
    from calibration import CalibrationSetup
    from calibration.discrepancy import discover

    t0 = time.perf_counter()
    d = discover(frames, CalibrationSetup(), opts, base_model=base)
    names = [f["name"] for f in d.found]
    b, a = d.before["channels"], d.after["channels"]
    worst = max(b, key=lambda c: b[c]["rmse"] or 0.0)
    te = d.theta_error or {}
    bias_b = max(abs(v["bias"]) for v in te["before"].values()) if te else None
    bias_a = max(abs(v["bias"]) for v in te["after"].values()) if te else None
    return {"truth": truth_name, "verdict": d.verdict, "found": names,
            "params": [f["params"] for f in d.found], "std": [f["std"] for f in d.found],
            "identified": bool(names) and truth_name is not None and names[0] == truth_name,
            "detected": bool(names) or d.verdict == "unknown effect",
            "channel": worst, "rmse_before": b[worst]["rmse"], "rmse_after": a[worst]["rmse"],
            "theta_bias_before": bias_b, "theta_bias_after": bias_a, "q": d.drift["q"],
            "mds": min_detectable(d), "seconds": time.perf_counter() - t0}


def scaled_param(name: str) -> str:
    """The parameter of effect ``name`` that its size scales (``EFFECTS``' ``{x}``)."""
    spec = EFFECTS[name][0]
    return spec[:spec.index("={x}")].replace(":", ",").split(",")[-1]


def min_detectable(d) -> dict:
    """{candidate: {parameter: minimum detectable size}} of the loop's first screen."""
    if not d.screens:
        return {}
    return {c["name"]: dict(zip(c["params"], c["min_detectable"], strict=True))
            for c in d.screens[0]["candidates"]}


def mds_reference(runs: list) -> dict:
    """{effect: median MDS of its scaled parameter} over the ``mds_reference`` runs."""
    refs = [r for r in runs if r["truth"] == "mds_reference" and r.get("mds")]
    out = {}
    for name in EFFECTS:
        v = [r["mds"][name][scaled_param(name)] for r in refs if name in r["mds"]]
        if v:
            out[name] = float(np.median(v))
    return out


def cmapss(base, path, method, results: Path, candidates=None):
    """The loop on NASA's C-MAPSS FD002 operating-point means: one 'unit', one cycle (constant
    theta), the channels C-MAPSS shows. Each row is a mean of many readings, but of many units
    too: the documented sensor noise (half the unit-to-unit scatter) is kept as each row's
    noise, i.e. each mean is weighted like one reading (conservative). ``Ps30`` is left out:
    in the C-MAPSS files it is not a static pressure below P30
    (:mod:`engine_model.analysis.reference`). The report goes to ``results``
    (``discrepancy_cmapss.md``, ``discrepancy_cmapss_candidates.md`` with ``candidates``)."""
    import pandas as pd

    from calibration import CalibrationSetup
    from calibration.discrepancy import DiscoverOptions, discover

    df = pd.read_csv(path)
    df = df.rename(columns={"alt_kft": "alt"})
    df["alt"] = df["alt"] * 1000.0
    sensors = tuple(c for c in ("Nf", "Nc", "T24", "T30", "T50", "P15", "P2", "P30")
                    if c in df.columns)
    d = discover([df], CalibrationSetup(sensors=sensors),
                 DiscoverOptions(method=method, drift=1e-3, candidates=candidates),
                 base_model=base)
    from calibration.discrepancy.discovery_report import markdown

    print(markdown(d))
    name = "discrepancy_cmapss" + ("_candidates" if candidates else "") + ".md"
    results.mkdir(parents=True, exist_ok=True)
    (results / name).write_text(markdown(d))
    return d


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--effects", default=",".join(EFFECTS))
    ap.add_argument("--sizes", default="1", help="multiples of the realistic size")
    ap.add_argument("--seeds", default="0")
    ap.add_argument("--units", default="1", help="tiny units, one run each")
    ap.add_argument("--null-fleets", type=int, default=2)
    ap.add_argument("--method", default="coarse")
    ap.add_argument("--candidates", help="comma-separated effects to test (default: the "
                    "loop's default list)")
    ap.add_argument("--cmapss", help="run on C-MAPSS operating-point means instead (e.g. "
                    "data_samples/cmapss-fd002-operating-points.csv)")
    ap.add_argument("--out", help="also write the runs of this table as one JSON array "
                    "(the --runs file already holds every run)")
    ap.add_argument("--results", type=Path, default=None,
                    help="the folder of the default --runs and --table and of the --cmapss "
                    "report (default out/discrepancy; the committed ones: "
                    "benchmarks/results)")
    ap.add_argument("--runs", default=None,
                    help="cache of finished runs (JSON lines): a rerun skips them (default "
                    "RESULTS/discrepancy_runs.jsonl.gz)")
    ap.add_argument("--table", default=None,
                    help="the Markdown table (default RESULTS/discrepancy_table.md)")
    ap.add_argument("--mds-units", action="store_true",
                    help="--sizes are multiples of each effect's minimum detectable size")
    ap.add_argument("--mds-fleets", type=int, default=3,
                    help="no-effect reference fleets for the minimum detectable sizes")
    ap.add_argument("--report-only", action="store_true",
                    help="write the table of the runs cached so far (a partial benchmark) "
                         "without running any")
    a = ap.parse_args(argv)
    results = OUT if a.results is None else a.results
    a.runs = a.runs or str(results / "discrepancy_runs.jsonl.gz")
    a.table = a.table or str(results / "discrepancy_table.md")
    from calibration.discrepancy import DiscoverOptions
    from engine_model.runtime.shared_model import default_model
    from engine_model.simulator import fleet

    base = default_model()
    if a.cmapss:
        return cmapss(base, a.cmapss, a.method, results,
                      tuple(a.candidates.split(",")) if a.candidates else None)
    opts = DiscoverOptions(method=a.method)
    cache_path = Path(a.runs)
    cache_path.parent.mkdir(parents=True, exist_ok=True)
    done = {}
    for r in read_runs(cache_path):
        done[_key(r)] = r
    print(f"# discrepancy benchmark ({platform.processor() or '?'}); "
          f"{len(done)} cached runs in {cache_path}")
    runs = []

    def run_cell(name, size, seed, unit):
        """The cached run of this cell, else run it (a no-effect fleet when ``name`` is None
        or ``mds_reference``) and cache it; None with --report-only."""
        key = (name, size, seed, unit, a.method)
        if key in done:
            return done[key]
        if a.report_only:
            return None
        if name in (None, "mds_reference"):
            df, _, _ = fleet.simulate("tiny", units=[unit], seed=seed, model=base)
            spec = "none"
            r = one_run(base, [df], opts, None)
            r["truth"] = name
        else:
            df, eff = simulate(base, name, size, unit, seed)
            spec = eff.spec()
            r = one_run(base, [df], opts, name)
        r.update(size=size, seed=seed, unit=unit, spec=spec, method=a.method)
        done[key] = r
        append_run(cache_path, r)
        print(json.dumps(r), flush=True)
        return r

    effects = list(filter(None, a.effects.split(",")))
    scale = dict.fromkeys(effects, 1.0)  # size -> multiple of the realistic size
    refs = [run_cell("mds_reference", 0.0, 2000 + k, 1 + k % 4) for k in range(a.mds_fleets)]
    mds = mds_reference([r for r in refs if r is not None])
    if a.mds_units:
        runs += [r for r in refs if r is not None]
        missing = [n for n in effects if n not in mds]
        if missing:
            print(f"no minimum detectable size yet for {', '.join(missing)}; run without "
                  "--report-only first")
            return None
        scale = {n: mds[n] / EFFECTS[n][1] for n in effects}
    # seed by seed (every effect and size, then a share of the no-effect fleets), so that an
    # interrupted benchmark has a balanced part of every cell
    seeds = [int(x) for x in a.seeds.split(",")]
    nulls = [(None, 0.0, 1000 + k, 1 + k % 4) for k in range(a.null_fleets)]
    per = -(-len(nulls) // len(seeds))
    cells = []
    for i, seed in enumerate(seeds):
        cells += [(name, float(f"{float(size) * scale[name]:.6g}"), seed, int(unit))
                  for size in a.sizes.split(",") for name in effects
                  for unit in a.units.split(",")]
        cells += nulls[i * per:(i + 1) * per]
    for cell in cells:
        r = run_cell(*cell)
        if r is not None:
            runs.append(r)
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(json.dumps(runs, indent=1))
    lines = table(runs, mds)
    if a.report_only and len(runs) < len(cells):
        lines.append(f"\npartial: {len(runs)} of {len(cells)} runs ({a.runs})")
    print("\n".join(lines))
    Path(a.table).parent.mkdir(parents=True, exist_ok=True)
    Path(a.table).write_text("\n".join(lines) + "\n")


def _key(r: dict) -> tuple:
    return (r["truth"], float(r["size"]), int(r["seed"]), int(r["unit"]),
            r.get("method", "ukf"))


def table(runs: list, mds: dict | None = None) -> list:
    """The Markdown table of ``runs`` (one row per effect and size: the size as a multiple of
    the realistic size and, where ``mds`` has it, of the minimum detectable size) and the
    no-effect line (the ``mds_reference`` fleets are listed apart)."""
    from scipy.stats import binom, binomtest

    mds = mds or {}
    out = ["| effect | size (x realistic) | x MDS | runs | detected | identified | channel RMSE "
           "before -> after | theta bias before -> after | verdicts |",
           "|---|---|---|---|---|---|---|---|---|"]
    keys = sorted({(r["truth"] or "none", r["size"]) for r in runs
                   if r["truth"] != "mds_reference"}, key=lambda k: (k[0], k[1]))
    for name, size in keys:
        rs = [r for r in runs if (r["truth"] or "none") == name and r["size"] == size]
        det = np.mean([r["detected"] for r in rs])
        idf = np.mean([r["identified"] for r in rs]) if name != "none" else float("nan")
        rb = np.mean([r["rmse_before"] for r in rs])
        ra = np.mean([r["rmse_after"] for r in rs])
        tb = np.mean([r["theta_bias_before"] for r in rs])
        ta = np.mean([r["theta_bias_after"] for r in rs])
        verdicts = ", ".join(sorted({r["verdict"] for r in rs}))
        x_mds = f"{size * EFFECTS[name][1] / mds[name]:.2g}" if name in mds else "-"
        out.append(f"| {name} | {size:g} | {x_mds} | {len(rs)} | {det:.0%} | "
                   f"{'-' if name == 'none' else f'{idf:.0%}'} | {rs[0]['channel']} "
                   f"{rb:.2f} -> {ra:.2f} | {tb:.2e} -> {ta:.2e} | {verdicts} |")
    nulls = [r for r in runs if r["truth"] is None]
    if nulls:
        out.append(f"\nno-effect fleets: {len(nulls)}")
        for what, hit in (("false discoveries (an effect added)", lambda r: bool(r["found"])),
                          ("'unknown effect'", lambda r: r["verdict"] == "unknown effect")):
            k = sum(map(hit, nulls))
            ci = binomtest(k, len(nulls)).proportion_ci(0.95)  # Clopper-Pearson
            out.append(f"- {what}: {k} ({k / len(nulls):.2%}; 95 % CI {ci.low:.2%}-"
                       f"{ci.high:.2%}; P(at least {k} | 1 %) = "
                       f"{binom.sf(k - 1, len(nulls), 0.01):.2g}): " + ", ".join(
                           f"seed {r['seed']} {'+'.join(r['found']) or r['verdict']}"
                           for r in nulls if hit(r)))
    refs = [r for r in runs if r["truth"] == "mds_reference"]
    if mds:
        out.append(f"\nminimum detectable size (80 % power, family-wise alpha; median of "
                   f"{len(refs) or 'the'} no-effect reference fleets): " + ", ".join(
                       f"{n} {v:.3g} ({v / EFFECTS[n][1]:.2g} x realistic)"
                       for n, v in mds.items()))
    return out


if __name__ == "__main__":
    main()
