"""Where each compressor's efficiency island should peak: the aerodynamic design point.

A civil turbofan's compressors are designed for cruise (Walsh & Fletcher, *Gas Turbine
Performance*, ch. 7.3; Cumpsty, *Jet Propulsion*, ch. 11): the blade angles give optimum
incidence there. This script solves the engine at the cruise point of the flight profiles
(35,000 ft, Mach 0.8, ISA, TRA 70: the middle of the profiles' cruise TRA) by continuation
from the sea-level-static design point, and prints for the fan, booster and HPC the relative
corrected speed and the blading flow coefficient ``phi_work`` there - the ``(n_pk, phi_opt1)``
that ``design.DesignSpec`` carries (moving the peak changes the efficiencies and hence the
match a little: run it again until the values stop changing). It does not fit anything to
the sea-level working line or to the C-MAPSS reference points. Run by hand:
``python benchmarks/map_design_point.py``.
"""

import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

# (casadi and the engine model are imported where they are used: ``--help`` answers at once)

CRUISE = (35000.0, 0.8, 70.0)


def solve_at(d, w_target, steps=30):
    import casadi as ca

    from engine_model.physics.turbofan import N_UNKNOWNS, X_DESIGN, cycle
    from engine_model.units import T_STD_R

    x = ca.SX.sym("x", N_UNKNOWNS)
    w = ca.SX.sym("w", 4)
    r, st = cycle(d, w, np.zeros(10), x)
    step = ca.Function("step", [x, w], [-ca.solve(ca.jacobian(r, x), r), r])
    speeds = ca.Function("speeds", [x, w], [st["n_fan"], st["n_lpc"], st["NRc"] / d.nrc_des])
    xx = np.array(X_DESIGN, float)
    w0 = np.array([0.0, 0.0, 100.0, T_STD_R])
    for lam in np.linspace(0.0, 1.0, steps + 1)[1:]:
        ww = w0 + lam * (np.asarray(w_target) - w0)
        for _ in range(60):
            dx, rr = step(xx, ww)
            if np.abs(np.asarray(rr)).max() < 1e-11:
                break
            dx = np.asarray(dx).ravel()
            xx = xx + min(1.0, 0.5 / max(np.abs(dx).max(), 1e-12)) * dx
        else:
            raise RuntimeError(f"no convergence at {ww}")
    return xx, [float(v) for v in speeds(xx, w_target)]


def main(argv=None):
    argparse.ArgumentParser(description=__doc__,
                            formatter_class=argparse.RawDescriptionHelpFormatter
                            ).parse_args(argv)
    from engine_model.physics.atmosphere import t2_from_flight
    from engine_model.physics.design import design_engine
    from engine_model.units import R_PER_K

    d = design_engine()
    alt, mach, tra = CRUISE
    T2 = float(t2_from_flight(alt, mach, 0.0)) * R_PER_K
    xx, speeds = solve_at(d, [alt, mach, tra, T2])
    print(f"cruise {alt:.0f} ft, Mach {mach}, TRA {tra}: beta fan/LPC/HPC = "
          f"{xx[0]:+.3f} {xx[1]:+.3f} {xx[2]:+.3f}")
    for name, cmap, beta, n in (("fan", d.fan, xx[0], speeds[0]), ("lpc", d.lpc, xx[1], speeds[1]),
                                ("hpc", d.hpc, xx[2], speeds[2])):
        print(f"{name}_map: n_pk={n:.3f} phi_opt1={float(cmap.phi_work(n, beta)):.3f} "
              f"(now n_pk={cmap.n_pk}, phi_opt1={cmap.phi_opt1})")


if __name__ == "__main__":
    main()
