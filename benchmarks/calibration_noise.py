"""The noise in the calibration's R on measured data: how consistent the filter is and how
well its theta_hat carries the wear, for each noise setting (C-MAPSS training files).

    python benchmarks/calibration_noise.py --data-dir ../shared/data/cmapss --subsets FD002 \\
        [--work out/cmapss] [--results benchmarks/results/calibration_noise] \\
        [--model-effects benchmarks/results/adaptation/fd002-adapted.json]

For each subset and each setting of :data:`SETTINGS` (``hyprog calibrate``'s ``--noise`` and
``--model-error``), the UKF with the paper's three parameters on every training unit (with
``--model-effects FILE``, every setting again with that adapted model), and:

- **mean NIS / m**: the normalised innovation squared ``nu^T S^-1 nu`` averaged over the
  fleet's samples and divided by the number of channels ``m``; 1 for a filter whose R and Q
  describe the data (Bar-Shalom, Li & Kirubarajan, *Estimation with Applications to Tracking
  and Navigation*, 2001, sec. 5.4);
- **jitter**: the std of theta_hat's change from one cycle to the next within a unit (what
  the filter lets through of the noise and of the model's error at each operating
  condition);
- **new** and **spread**: the mean over conditions of theta_hat's condition means over
  cycles 1-20, and the largest minus the smallest of them (new engines should be near 0 and
  should not depend on the condition);
- **wear**: the median over units of theta_hat's change from cycles 1-20 to the last 10
  cycles, and **wear / jitter**, the signal of the wear against the cycle-to-cycle scatter.

The last setting is ``--model-error consistent`` (:mod:`calibration.consistency`): its row
shows the value found and, in ``seconds``, the search as well. It trains nothing and reads
the RUL only to find the last 10 cycles; the settings that
``benchmarks/cmapss.py --noise --model-error`` cross-validates are chosen from this table.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # this checkout, not whichever tree is installed
sys.path.insert(0, str(ROOT / "benchmarks"))
from common import imported  # noqa: E402

#: (``--noise``, ``--model-error``) settings compared.
SETTINGS = (("model", 0.0), ("data", 0.0), ("model", 0.003), ("data", 0.001), ("data", 0.003),
            ("data", 0.005), ("data", 0.01), ("data", 0.015), ("data", "consistent"))
EARLY, LATE = 20, 10


def measure(raw: Path, noise: str, model_error: float | str,
            adapted: Path | None = None) -> dict:
    """Calibrate every unit of ``raw`` with the setting (and the adapted model ``adapted``);
    the module docstring's figures. ``model_error="consistent"``: the one
    :func:`calibration.consistency.consistent_model_error` finds (its value in the row)."""
    import warnings

    from calibration import CalibrationSetup, UnobservableWarning
    from calibration.calibrate_fleet import calibrate_fleet, features_of

    effects = ()
    if adapted is not None:
        from calibration.adaptation import load_adapted
        effects = load_adapted(adapted).effects
    t0 = time.perf_counter()
    chosen, setup = model_error, CalibrationSetup(noise=noise)
    if model_error == "consistent":
        from calibration.consistency import with_consistent_model_error
        setup, _ = with_consistent_model_error(setup, raw, effects)
    else:
        setup = CalibrationSetup(noise=noise, model_error=model_error)
    model_error = setup.model_error
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnobservableWarning)
        run = calibrate_fleet(raw, "ukf", setup, check_data=False, effects=effects)
    seconds = time.perf_counter() - t0
    res = list(run.results.values())
    n = np.array([r.diagnostics["n_samples"] - r.diagnostics["n_nonconverged"] for r in res])
    nis = np.array([r.diagnostics["nis_mean"] for r in res])
    m = res[0].diagnostics["nis_dof"]
    df = features_of(run).sort_values(["unit", "cycle"])
    cols = [q + "_hat" for q in run.setup.params]
    early = df[df["cycle"] <= EARLY]
    cond = early.groupby("condition")[cols].mean()
    jitter = df.groupby("unit")[cols].diff().std()
    wear = (df[df["RUL"] < LATE].groupby("unit")[cols].mean()
            - early.groupby("unit")[cols].mean()).median()
    row = {"model": "adapted" if adapted else "as designed", "noise": noise,
           "model_error": (f"{model_error:.4g} (consistent)" if chosen == "consistent"
                           else model_error),
           "NIS / m": float(np.nansum(nis * n) / n[np.isfinite(nis)].sum() / m),
           "seconds": round(seconds, 1)}
    for c in cols:
        q = c.removesuffix("_mod_hat")
        row[f"{q} jitter %"] = 100 * jitter[c]
        row[f"{q} new %"] = 100 * cond[c].mean()
        row[f"{q} spread %"] = 100 * (cond[c].max() - cond[c].min())
        row[f"{q} wear %"] = 100 * wear[c]
        row[f"{q} wear / jitter"] = abs(wear[c]) / jitter[c]
    return row


def markdown(t: pd.DataFrame) -> str:
    """``t`` as a Markdown table, numbers to three significant digits."""
    def cell(v):
        return f"{v:.3g}" if isinstance(v, float) else str(v)
    lines = ["| " + " | ".join(t.columns) + " |", "|---" * len(t.columns) + "|"]
    lines += ["| " + " | ".join(cell(v) for v in r) + " |" for r in t.itertuples(index=False)]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, required=True)
    ap.add_argument("--subsets", default="FD002")
    ap.add_argument("--work", type=Path, default=Path("out/cmapss"))
    ap.add_argument("--results", type=Path, default=None)
    ap.add_argument("--model-effects", type=Path, default=None,
                    help="an adapted model (hyprog adapt): every setting again with it")
    a = ap.parse_args(argv)
    a.work.mkdir(parents=True, exist_ok=True)
    text = []
    for subset in a.subsets.split(","):
        raw = imported(a.data_dir, a.work, subset)
        rows = []
        for adapted in (None, a.model_effects) if a.model_effects else (None,):
            for noise, me in SETTINGS:
                rows.append(measure(raw, noise, me, adapted))
                print(f"{subset} {rows[-1]['model']} --noise {noise} --model-error {me}: "
                      f"NIS/m {rows[-1]['NIS / m']:.3g}", file=sys.stderr, flush=True)
        t = pd.DataFrame(rows)
        md = f"# {subset}: the noise in the calibration's R\n\n{markdown(t)}\n"
        text.append(md)
        if a.results:  # one table per subset: RESULTS/fd00x.md and .csv
            a.results.mkdir(parents=True, exist_ok=True)
            t.to_csv(a.results / f"{subset.lower()}.csv", index=False, float_format="%.4g")
            (a.results / f"{subset.lower()}.md").write_text(md)
    print("\n".join(text))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
