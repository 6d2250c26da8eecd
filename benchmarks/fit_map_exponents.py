"""Re-derive the compressor-map speed exponents of DesignSpec (k_flow, k_head).

Compressor designers put the peak-efficiency ridge of a map on the engine's working line.
This script solves the sea-level-static working line at TRA 50 by continuation from the
design point, then moves each compressor's flow and head speed exponents until the
operating point sits on the ridge (beta = 0), starting from textbook values (head ~ n^2,
flow ~ n^1.1 / n^1.6 / n^2.4 for fan / LPC / HPC). It prints the exponents that
``design.DesignSpec`` carries. Run by hand: ``python benchmarks/fit_map_exponents.py``.
"""

import os
import sys
from dataclasses import replace

import casadi as ca
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
from engine_model.design import DesignSpec, design_engine  # noqa: E402
from engine_model.turbofan import X_DESIGN, cycle  # noqa: E402
from engine_model.units import T_STD_R  # noqa: E402


def working_point(d, w_target):
    x = ca.SX.sym("x", 7)
    w = ca.SX.sym("w", 4)
    th = ca.SX.sym("th", 10)
    r, st = cycle(d, w, th, x)
    step = ca.Function("s", [x, w, th], [-ca.solve(ca.jacobian(r, x), r), r])
    n_lpc = ca.Function("n", [x, w, th], [st["n_lpc"], st["n_fan"]])
    xx = np.array(X_DESIGN, float)
    w0 = np.array([0.0, 0.0, 100.0, T_STD_R])
    for lam in np.linspace(0, 1, 21)[1:]:
        ww = w0 + lam * (np.asarray(w_target) - w0)
        for _ in range(50):
            dx, rr = step(xx, ww, np.zeros(10))
            if np.abs(np.asarray(rr)).max() < 1e-11:
                break
            xx = xx + np.asarray(dx).ravel()
    nl, nf = (float(v) for v in n_lpc(xx, ww, np.zeros(10)))
    return xx, nf, nl


def main():
    spec = DesignSpec()
    start = {"fan_map": (1.1, 2.0), "lpc_map": (1.6, 2.0), "hpc_map": (2.4, 2.0)}
    maps = {k: dict(getattr(spec, k), k_flow=v[0], k_head=v[1]) for k, v in start.items()}
    for it in range(8):
        d = design_engine(replace(spec, **maps))
        xx, n_fan, n_lpc = working_point(d, [0.0, 0.0, 50.0, T_STD_R])
        print(f"iteration {it}: beta fan/LPC/HPC = {xx[0]:+.5f} {xx[1]:+.5f} {xx[2]:+.5f}")
        for key, beta, n in (("fan_map", xx[0], n_fan), ("lpc_map", xx[1], n_lpc),
                             ("hpc_map", xx[2], xx[3])):
            m = maps[key]
            m["k_flow"] += np.log(1 - m["s_flow"] * beta) / np.log(n)
            m["k_head"] += np.log(1 + m["s_head"] * beta) / np.log(n)
        if max(abs(xx[:3])) < 1e-6:
            break
    for key, m in maps.items():
        print(f"{key}: k_flow={m['k_flow']:.3f} k_head={m['k_head']:.3f}")


if __name__ == "__main__":
    main()
