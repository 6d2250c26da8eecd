"""Does a loss of booster flow capacity consume the booster's stall margin at sea-level
take-off? The engine model beside an independent stage-stacking analysis (issue 12).

Run by hand: ``python benchmarks/booster_stage_stacking.py``. It prints two tables, kept in
``benchmarks/results/booster_stage_stacking.md``:

1. **The engine model.** The booster's stall margin ``SmLPC`` (at constant corrected speed)
   for the new engine, with LPC flow capacity -2 %, and with HPC flow capacity -2 %. The
   points are SLS at TRA 100, 80 and 60, climb (20 kft, Mach 0.7, TRA 90) and cruise
   (35 kft, Mach 0.8, TRA 70).
2. **Stage stacking** (``engine_model.physics.stage_stacking``). A booster of 3 or 4 repeating
   stages at the model's design pressure ratio, inlet temperature and pressure, and peak
   efficiency. It runs behind a fixed downstream throttle (the HPC's corrected flow), at
   relative speeds 1.0, 0.9 and 0.8, and at speed 1.0 behind the exit flow that the engine's
   own matching gives at SLS take-off (table 1), with the exit-flow change at which the
   margin is unchanged (break-even). Every stage is given a blockage, scaled so that the flow
   at design speed and design pressure ratio falls by 2 %. Three distributions are tried:
   uniform, front-weighted linear (1, 2/3, 1/3, ... of the first stage's), and the first
   stage alone (Aker & Saravanamuttoo: fouling is heaviest on the front stages). The
   loss-bucket curvature ``c_eta`` takes 1, 2 and 4, the stall point is either the peak of
   the stage characteristic or ``phi_s = 0.8``, and the fouling loss ``k`` (the work and
   efficiency the fouled stages lose with their blockage) 0 (pure blockage) or 0.5: 2 x 3 x 2
   x 2 x 3 = 72 variants, 216 cases behind the fixed exit flow (three speeds each) and 72
   at the engine's. Each cell is the change of the constant-speed stall margin [points].
"""

import argparse
import os
import platform
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

# (scipy and the engine model are imported where they are used: ``--help`` answers at once)

POINTS = {"SLS TRA 100": (0.0, 0.0, 100.0), "SLS TRA 80": (0.0, 0.0, 80.0),
          "SLS TRA 60": (0.0, 0.0, 60.0), "climb": (20000.0, 0.7, 90.0),
          "cruise": (35000.0, 0.8, 70.0)}
SPEEDS = (1.0, 0.9, 0.8)


def engine_table(model):
    """Print the engine's SmLPC table; return the booster exit corrected flow change [-] for
    LPC flow -2 % at each point."""
    from engine_model import THETA_NAMES
    from engine_model.physics.atmosphere import t2_from_flight

    w = np.array([[a, m, t, 1.8 * float(t2_from_flight(a, m))] for a, m, t in POINTS.values()])
    rows, exit_flow = {}, {}
    for label, name in (("new", None), ("LPC flow -2 %", "LPC_flow_mod"),
                        ("HPC flow -2 %", "HPC_flow_mod")):
        th = np.zeros((len(w), len(THETA_NAMES)))
        if name:
            th[:, THETA_NAMES.index(name)] = -0.02
        ev = model.evaluate(w, th)
        assert ev.converged.all()
        rows[label] = ev.SmLPC.to_numpy()
        # the booster's exit corrected flow (W22 passes the booster; the VBVs bleed after it)
        exit_flow[label] = (ev.W22 * np.sqrt(ev.T24) / ev.P24).to_numpy()
    print("| SmLPC [%] | " + " | ".join(POINTS) + " |")
    print("|---|" + "---|" * len(POINTS))
    for label, sm in rows.items():
        cells = [f"{v:.3f}" if label == "new" else f"{v:.3f} ({v - n:+.3f})"
                 for v, n in zip(sm, rows["new"], strict=True)]
        print(f"| {label} | " + " | ".join(cells) + " |")
    for label in ("LPC flow -2 %", "HPC flow -2 %"):
        d = exit_flow[label] / exit_flow["new"] - 1.0
        print(f"| booster exit corrected flow, {label} [%] | "
              + " | ".join(f"{100 * x:+.2f}" for x in d) + " |")
    return exit_flow["LPC flow -2 %"] / exit_flow["new"] - 1.0


def stacking_table(design_point, d_exit_sls):
    """Print the stacking table; ``d_exit_sls`` is the engine's booster exit-flow change at
    SLS take-off for LPC flow -2 %."""
    from scipy.optimize import brentq

    from engine_model.physics.stage_stacking import StageStack

    kw = dict(pr_des=design_point["pr_lpc"], T_in=design_point["T21"],
              P_in=design_point["P21"], w_des=design_point["W25"], eta_pk=0.88)
    print("| stages | c_eta | phi_s / phi_d | k | design SM at n = 1.0 / 0.9 / 0.8 | fouling | "
          + " | ".join(f"dSM n = {n}" for n in SPEEDS)
          + f" | dSM n = 1.0, exit flow {100 * d_exit_sls:+.2f} % | break-even exit flow |"
          " stalling stage |")
    print("|---|---|---|---|---|---|" + "---|" * len(SPEEDS) + "---|---|---|")
    changes, matched, even = [], [], []
    for n_st in (3, 4):
        dists = {"uniform": np.ones(n_st), "front-linear": np.linspace(1.0, 1.0 / n_st, n_st),
                 "first stage": np.eye(n_st)[0]}
        for c_eta in (1.0, 2.0, 4.0):
            for phi_s in (None, 0.8):
                for k in (0.0, 0.5):
                    st = StageStack(n_stages=n_st, c_eta=c_eta, phi_s=phi_s, fouling_loss=k,
                                    **kw)
                    sm0 = [st.stall_margin(n) for n in SPEEDS]
                    for dname, wts in dists.items():
                        f = st.blockage_for_capacity(wts, -0.02)
                        d = [st.stall_margin(n, f) - s0
                             for n, s0 in zip(SPEEDS, sm0, strict=True)]
                        dm = st.stall_margin(1.0, f, st.exit_flow_des * (1 + d_exit_sls)) - sm0[0]
                        # exit-flow change at which the margin at n = 1 is unchanged
                        x0 = brentq(lambda x, st=st, f=f, s0=sm0[0]: st.stall_margin(
                            1.0, f, st.exit_flow_des * (1.0 + x)) - s0, -0.06, 0.02)
                        changes += d
                        matched.append(dm)
                        even.append(x0)
                        stall = "/".join(str(st.surge_point(n, f)[2] + 1) for n in SPEEDS)
                        print(f"| {n_st} | {c_eta:g} | {st.phi_s:.3f} | {k:g} | "
                              + " / ".join(f"{s:.2f}" for s in sm0) + f" | {dname} | "
                              + " | ".join(f"{x:+.2f}" for x in d)
                              + f" | {dm:+.2f} | {100 * x0:+.2f} % | {stall} |")
    changes, matched, even = np.array(changes), np.array(matched), np.array(even)
    print(f"\nstall-margin change behind the design exit flow, all {changes.size} cases: "
          f"min {changes.min():+.2f}, max {changes.max():+.2f} points; "
          f"negative in {int((changes < 0).sum())}")
    print(f"at the engine's exit flow ({100 * d_exit_sls:+.2f} %), n = 1, all {matched.size} "
          f"cases: min {matched.min():+.2f}, max {matched.max():+.2f}; "
          f"negative in {int((matched < 0).sum())}")
    print(f"break-even exit-flow change: {100 * even.min():+.2f} to {100 * even.max():+.2f} %")


def main(argv=None):
    argparse.ArgumentParser(description=__doc__,
                            formatter_class=argparse.RawDescriptionHelpFormatter
                            ).parse_args(argv)
    from engine_model.runtime.shared_model import default_model

    t0 = time.time()
    model = default_model()
    print(f"machine: {platform.machine()}, {os.cpu_count()} cores, python "
          f"{platform.python_version()}\n")
    print("## 1. Engine model: booster stall margin at constant corrected speed\n")
    d_exit = engine_table(model)
    print("\n## 2. Stage stacking: booster behind a fixed downstream corrected flow, "
          "flow capacity -2 %\n")
    stacking_table(model.design.point, float(d_exit[0]))
    print(f"\nwall time {time.time() - t0:.1f} s")


if __name__ == "__main__":
    main()
