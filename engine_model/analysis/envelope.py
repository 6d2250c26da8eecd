"""The envelope sweep: solve random points of the civil envelope (:mod:`sampling`) and report
the convergence rate, the speed and the points that fail (``hyprog model envelope``).

Report (a JSON-ready dict): ``n_points``, ``seed``, ``n_failed``, ``convergence_rate``
(fraction converged), ``seconds`` (wall time of the batch solve), ``points_per_second``
(None when the clock did not advance), ``failures`` (one record per failing point: ``row``
(0-based draw index), ``alt Mach TRA T2``, the ten theta, ``dT_isa`` [K], ``residual_norm``).
"""

from __future__ import annotations

import time
from typing import Any

from engine_model.channels import THETA_NAMES, W_NAMES

from .sampling import envelope_points


def envelope_report(model: Any, n: int, seed: int = 0) -> dict[str, Any]:
    """Solve ``n`` random envelope points with ``model`` (anything with the
    :meth:`engine_model.EngineModel.evaluate` signature) and report (module doc)."""
    pts = envelope_points(n, seed)
    t0 = time.perf_counter()
    out = model.evaluate(pts[[*W_NAMES, *THETA_NAMES]])
    elapsed = time.perf_counter() - t0
    ok = out["converged"].to_numpy(bool)
    bad = pts.loc[~ok].copy()
    bad["residual_norm"] = out.loc[~ok, "residual_norm"]
    failures = [{"row": int(i), **row} for i, row in zip(bad.index, bad.to_dict("records"),
                                                          strict=True)]
    return {
        "n_points": n,
        "seed": seed,
        "n_failed": int((~ok).sum()),
        "convergence_rate": float(ok.mean()),
        "seconds": elapsed,
        "points_per_second": n / elapsed if elapsed > 0 else None,
        "failures": failures,
    }
