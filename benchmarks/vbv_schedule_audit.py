"""Stability audit of the booster: the variable-bleed-valve (VBV) opening a new engine needs
over the envelope, and whether a schedule on the controller's inputs can give it.

Run by hand: ``python benchmarks/vbv_schedule_audit.py [--check | --propose]`` (about 2
minutes).

A real VBV schedule is designed this way: find, over the envelope, the opening that keeps the
booster a minimum stall margin from surge, then tabulate it against what the engine computer
measures (on the CFM56, the corrected core speed ``N2K25``, with a fan-speed term; Linke-
Diesinger, *Systems of Commercial Turbofan Engines*, Springer 2008, ch. 4 and 8; Walsh &
Fletcher, *Gas Turbine Performance*, 2nd ed., ch. 5.2.6 and 7.2).

Audit. The new engine is solved on a grid of the envelope (altitude 0-42,000 ft; Mach 0, 0.1
and 0.2 at every altitude, as the sampled envelope starts at Mach 0, and 0.25 in flight, the
350 kt CAS limit and a point between; ISA -15/0/+15 K; TRA 20-100 by 5) with the valves held at
fixed openings ``f`` = 0, 0.025, ... 0.40 of the booster exit flow (an override of the model's
``W_vbv`` hook; each opening starts from the previous one's solution). Per point
(:func:`requirement`): ``need``, the opening at which the booster stall margin ``SmLPC``
reaches ``SM_TARGET`` (or the best margin where none does: ground idle, whose whole booster
speed line spans a pressure ratio of about 1.02), the corrected core speed ``n_hpc`` and fan
speed ``NRf`` there, and ``cap``, the largest opening the booster can pass (beyond it the
booster chokes and the engine has no steady state). A schedule on a variable exists only if, in
every band of it, ``(1 + ALLOWANCE) need <= cap`` for every pair of points (``need <= cap``
where the target is out of reach): the tables print the largest need and the smallest cap per
band of ``n_hpc`` and per cell of ``(n_hpc, NRf)``, and count the conflicts.

The audit also scans schedules on one combined variable ``v = n_hpc - b NRf - c Mach``
(:func:`combined_variable_scan`), over the flight points at Mach >= 0.25, all flight points, and
every point (the ground included).

``--check`` solves the same grid with the model as it is (its own schedule) and prints the
convergence and the lowest booster stall margin per (altitude, Mach). ``--propose`` designs a
schedule from the audit (:func:`propose`: the fan and Mach biases of the combined variable,
the knots of the opening with a ``SCHEDULE_ALLOWANCE`` margin, the core-speed closing band
and the ground limit) and prints it.
"""

import argparse
import os
import sys
import time

import numpy as np
import pandas as pd

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))
from engine_model import OUTPUT_NAMES, THETA_NAMES, EngineModel
from engine_model.analysis.sampling import MAX_CAS_KT  # noqa: E402
from engine_model.physics import atmosphere  # noqa: E402
from engine_model.physics.bleed_schedule import BleedValveSchedule, FixedOpening  # noqa: E402
from engine_model.runtime.shared_model import default_model  # noqa: E402
from engine_model.units import KT_TO_MS, k_to_r  # noqa: E402

OPENINGS = np.round(np.arange(0.0, 0.4001, 0.025), 3)
SM_TARGET = 3.0  # booster stall margin [%] the schedule should keep where an opening can
ALLOWANCE = 0.10  # a schedule's opening over the largest need it covers (relative)
SCHEDULE_ALLOWANCE = 0.05  # the same, for the schedule --propose designs
BAND = 0.0125  # band of corrected core speed n_hpc (fraction of design)
CELL = (0.025, 0.05)  # cell of (n_hpc, NRf / NRf_des)


def envelope_grid():
    """Rows (alt ft, Mach, TRA %, dT_isa K, T2 degR) of the audit grid (module doc)."""
    rows = []
    for alt in (0, 5000, 10000, 15000, 20000, 25000, 30000, 35000, 39000, 42000):
        m_cas = min(0.84, float(atmosphere.mach_from_cas(MAX_CAS_KT * KT_TO_MS, alt)))
        m_low = 0.0 if alt == 0 else 0.25
        slow = {0.0, 0.1, 0.2}  # in flight too: the sampled envelope starts at Mach 0
        for mach in sorted(slow | {m_low, round(0.5 * (m_low + m_cas), 3), round(m_cas, 3)}):
            for dT in (-15.0, 0.0, 15.0):
                t2 = k_to_r(float(atmosphere.t2_from_flight(alt, mach, dT)))
                for tra in np.arange(20.0, 100.1, 5.0):
                    rows.append((alt, mach, tra, dT, t2))
    return np.array(rows)


def sweep(rows):
    """Solve every row at every fixed opening; long table with SmLPC, n_hpc, converged."""
    model = EngineModel(effects=[FixedOpening()])
    w = rows[:, [0, 1, 2, 4]]
    th = np.zeros((len(w), len(THETA_NAMES)))
    nrc_des = model.design.nrc_des
    out, x_prev = [], None
    for f in OPENINGS:
        p = np.full((len(w), 1), f)
        res = model.solve(w, th, p) if x_prev is None else model.solve(w, th, p, x0=x_prev)
        if x_prev is not None and (~res.converged).any():
            bad = ~res.converged
            again = model.solve(w[bad], th[bad], p[bad])
            res.x[bad], res.converged[bad] = again.x, again.converged
        y = pd.DataFrame(model.outputs_at(res.x, w, th, p), columns=OUTPUT_NAMES)
        out.append(pd.DataFrame({"row": np.arange(len(w)), "f": f, "ok": res.converged,
                                 "SmLPC": y["SmLPC"], "n_hpc": y["NRc"] / nrc_des,
                                 "nrf": y["NRf"] / model.design.spec.Nf_rpm}))
        x_prev = res.x if x_prev is None else np.where(res.converged[:, None], res.x, x_prev)
        print(f"  opening {f:.3f}: {res.converged.mean():6.1%} converged", file=sys.stderr)
    return pd.concat(out, ignore_index=True)


def requirement(curve):
    """``(need, n_hpc, nrf, cap, reached)`` of one point from its sweep.

    The sweep is read from its first solved opening over the run of consecutive solved
    openings that follows (an opening the booster cannot pass - it chokes - has no steady
    state). ``need``: the opening at which SmLPC first reaches the target (linear
    interpolation; the first solved opening when that already does: a point past its surge
    line without bleed has no solution at 0); where no opening reaches it (ground idle, where
    the whole speed line spans a pressure ratio of about 1.02) the opening of the largest
    margin, ``reached`` False. ``n_hpc``, ``nrf``: the corrected core and fan speeds there
    (fractions of design). ``cap``: the
    largest opening of the run. None when nothing was solved."""
    c = curve[curve.ok].sort_values("f")
    f, sm, n, nf = c.f.to_numpy(), c.SmLPC.to_numpy(), c.n_hpc.to_numpy(), c.nrf.to_numpy()
    if len(f) == 0:
        return None
    step = OPENINGS[1] - OPENINGS[0]
    end = 1
    while end < len(f) and f[end] - f[end - 1] < 1.5 * step:
        end += 1
    f, sm, n, nf = f[:end], sm[:end], n[:end], nf[:end]
    if sm[0] >= SM_TARGET:
        return f[0], n[0], nf[0], f[-1], True
    for k in range(1, len(f)):
        if sm[k] >= SM_TARGET:
            a = (SM_TARGET - sm[k - 1]) / (sm[k] - sm[k - 1])
            return (f[k - 1] + a * (f[k] - f[k - 1]), n[k - 1] + a * (n[k] - n[k - 1]),
                    nf[k - 1] + a * (nf[k] - nf[k - 1]), f[-1], True)
    k = int(np.argmax(sm))
    return f[k], n[k], nf[k], f[-1], False


def conflicts(req, keys):
    """Per group of ``keys``: points, largest need, smallest cap, and whether a schedule on
    those keys can open enough everywhere without choking the booster anywhere: a conflict
    where the largest opening wanted (``(1 + ALLOWANCE) need``; the need itself where the
    target is out of reach) exceeds the smallest cap."""
    want = req.assign(want=np.where(req.reached, (1.0 + ALLOWANCE) * req.need, req.need))
    g = want.groupby(keys).agg(points=("need", "size"),
                               no_bleed=("need", lambda v: (v == 0).sum()),
                               need=("need", "max"), want=("want", "max"), cap=("cap", "min"),
                               out_of_reach=("reached", lambda v: (~v).sum()))
    g["conflict"] = g.want > g.cap + 1e-9
    return g


def requirements(rows):
    """The sweep's per-point requirements (:func:`requirement`) as a table."""
    long = sweep(rows)
    reqs = []
    for r, curve in long.groupby("row"):
        got = requirement(curve)
        if got is not None:
            reqs.append(dict(row=r, alt=rows[r, 0], Mach=rows[r, 1], TRA=rows[r, 2],
                             dT=rows[r, 3], need=got[0], n_hpc=got[1], nrf=got[2],
                             cap=got[3], reached=got[4]))
    return pd.DataFrame(reqs)


def one_variable_conflicts(v, want, cap, window=0.003):
    """``(count, worst)``: points whose ``cap`` is below the ``want`` of a point within
    ``window`` of the schedule variable ``v``, and the largest such excess."""
    o = np.argsort(v)
    v, want, cap = np.asarray(v)[o], np.asarray(want)[o], np.asarray(cap)[o]
    lo, hi = np.searchsorted(v, v - window), np.searchsorted(v, v + window)
    excess = np.array([want[a:b].max() - c for a, b, c in zip(lo, hi, cap, strict=True)])
    bad = excess > 1e-9
    return int(bad.sum()), float(excess[bad].max()) if bad.any() else 0.0


def flight_weight(req):
    """The throttle schedule's ground/flight weight (0 on the ground, 1 in flight) per point."""
    return np.asarray(default_model().design.spec.throttle.flight_weight(
        req.Mach.to_numpy(), req.alt.to_numpy()), float).ravel()


def ranked(scan):
    """The ``(b, c)`` pairs of a scan, fewest conflicts first, then smallest excess, then
    smallest Mach coefficient."""
    return sorted(scan, key=lambda k: (scan[k][0], scan[k][1], k[1]))


def combined_variable_scan(req, sets):
    """Conflicts of a schedule on one combined variable ``v = n_hpc - b NRf - c Mach``
    (corrected speeds as fractions of design) per set of points, for every ``b`` in 0-0.6
    (step 0.05) and ``c`` in 0-0.3 (step 0.025); wanted opening ``1.05 need`` (0 where the
    target is out of reach). Prints the best pairs; returns ``{set name: {(b, c): (count,
    worst)}}``."""
    want = np.where(req.reached, (1.0 + SCHEDULE_ALLOWANCE) * req.need, 0.0)
    cap = req.cap.to_numpy()
    scans = {}
    for name, mask in sets.items():
        scan = {}
        for b in np.round(np.arange(0.0, 0.601, 0.05), 2):
            for c in np.round(np.arange(0.0, 0.301, 0.025), 3):
                v = (req.n_hpc - b * req.nrf - c * req.Mach).to_numpy()
                scan[(b, c)] = one_variable_conflicts(v[mask], want[mask], cap[mask])
        best = ranked(scan)[:4]
        print(f"\n{name} ({int(mask.sum())} points): best pairs, and b = 0.35 without Mach\n")
        print("| NRf coefficient b | Mach coefficient c | points in conflict | largest excess |")
        print("|---|---|---|---|")
        for k in best + [(0.35, 0.0)]:
            print(f"| {k[0]:.2f} | {k[1]:.3f} | {scan[k][0]} | {scan[k][1]:.3f} |")
        scans[name] = scan
    return scans


def audit():
    rows = envelope_grid()
    print(f"audit grid: {len(rows)} points, openings {OPENINGS[0]}-{OPENINGS[-1]}",
          file=sys.stderr)
    t0 = time.perf_counter()
    req = requirements(rows)
    req["band"] = np.floor(req.n_hpc / BAND + 1e-9) * BAND
    req["cell_n"] = np.floor(req.n_hpc / CELL[0] + 1e-9) * CELL[0]
    req["cell_f"] = np.floor(req.nrf / CELL[1] + 1e-9) * CELL[1]
    one = conflicts(req, ["band"])
    two = conflicts(req, ["cell_n", "cell_f"])
    print(f"booster stability audit: target SmLPC >= {SM_TARGET} %, allowance {ALLOWANCE:.0%}, "
          f"{len(rows)} envelope points, {len(req)} solved at some opening, "
          f"{(~req.reached).sum()} where no opening reaches the target "
          f"({time.perf_counter() - t0:.0f} s)\n")
    print(f"Schedule on corrected core speed alone: {int(one.conflict.sum())} of {len(one)} "
          f"bands in conflict; on (core, fan) corrected speeds: {int(two.conflict.sum())} of "
          f"{len(two)} cells in conflict.\n")
    print("| n_hpc band | points | need no bleed | largest need | smallest cap | target out of "
          "reach | conflict |")
    print("|---|---|---|---|---|---|---|")
    for b, r in one.iterrows():
        print(f"| {b:.4f}-{b + BAND:.4f} | {r.points} | {r.no_bleed} | {r.need:.3f} | "
              f"{r.cap:.3f} | {r.out_of_reach} | {'**yes**' if r.conflict else 'no'} |")
    cols = sorted(req.cell_f.unique())
    print("\nlargest need / smallest cap per cell; rows n_hpc, columns NRf (fractions of "
          "design); * = conflict\n")
    print("| n_hpc \\ NRf | " + " | ".join(f"{c:.2f}" for c in cols) + " |")
    print("|---|" + "---|" * len(cols))
    for n in sorted(req.cell_n.unique()):
        cells = []
        for c in cols:
            if (n, c) in two.index:
                r = two.loc[(n, c)]
                cells.append(f"{r.need:.2f}/{r.cap:.2f}{'*' if r.conflict else ''}")
            else:
                cells.append("")
        print(f"| {n:.3f} | " + " | ".join(cells) + " |")

    weight = flight_weight(req)
    combined_variable_scan(req, {
        "in flight, Mach >= 0.25": (weight > 0.99) & (req.Mach >= 0.25).to_numpy(),
        "in flight, every Mach": weight > 0.99,
        "every point": np.ones(len(req), bool)})


def propose():
    """Design the VBV schedule from the audit (the rules in engine_model.physics.bleed_schedule's
    module doc) and print it: the fan and Mach biases, the knots of F, the core-speed closing
    band and the ground limit."""
    req = requirements(envelope_grid())
    want = np.where(req.reached, (1.0 + SCHEDULE_ALLOWANCE) * req.need, 0.0)
    weight = flight_weight(req)
    fl, ground = weight > 0.99, weight < 0.01
    print(f"{len(req)} points: {fl.sum()} in flight, {ground.sum()} on the ground\n")
    bias, mach_bias = ranked(combined_variable_scan(req, {"in flight": fl})["in flight"])[0]
    v = (req.n_hpc - bias * req.nrf - mach_bias * req.Mach).to_numpy()
    v_design = 1.0 - bias
    step = 0.01
    knots = []
    for t in np.round(np.arange(np.floor(v[fl].min() / step) * step, v_design + 1e-9, step), 3):
        early = fl & (v >= t - 0.5 * step)
        f = 0.0 if t >= v_design - 1e-9 else np.ceil(want[early].max() / 0.005 - 1e-9) * 0.005
        knots.append((float(t), round(float(f), 3) + 0.0))
        if f == 0.0:  # shut from here on
            break
    print(f"\nfan bias {bias:.2f}, Mach bias {mach_bias:.3f}; knots (v, opening): {tuple(knots)}")
    need, close = req.need.to_numpy(), None
    for a in np.round(np.arange(0.86, 0.961, 0.01), 2):
        sched = BleedValveSchedule(knots=tuple(knots), fan_bias=bias, mach_bias=mach_bias,
                                   core_close=(a, a + 0.04))
        f = np.asarray(sched.unlimited_opening(req.n_hpc.to_numpy(), req.nrf.to_numpy(),
                                               req.Mach.to_numpy()), float).ravel()
        short = int((fl & req.reached.to_numpy() & (f < need - 1e-9)).sum())
        print(f"core closing band {a:.2f}-{a + 0.04:.2f}: {short} flight points short of need")
        if short == 0 and close is None:
            close = (float(a), float(a + 0.04))
    print(f"\nearliest closing band with no flight point short: {close}")
    # the low-speed limit is chosen by hand from this table (bleed_schedule's module doc) and
    # verified with --check
    slow = req[req.nrf < 0.46].assign(ground=ground[(req.nrf < 0.46).to_numpy()])
    print("\npoints below corrected fan speed 0.46 (largest need, smallest cap):\n")
    print("| alt ft | Mach | on the ground | NRf | largest need | smallest cap | target reached |")
    print("|---|---|---|---|---|---|---|")
    for (alt, mach), g in slow.groupby(["alt", "Mach"]):
        print(f"| {alt:.0f} | {mach:.3f} | {'yes' if g.ground.all() else 'no'} | "
              f"{g.nrf.min():.3f}-{g.nrf.max():.3f} | {g.need.max():.3f} | {g.cap.min():.3f} | "
              f"{int(g.reached.sum())}/{len(g)} |")


def check():
    rows = envelope_grid()
    ev = default_model().evaluate(pd.DataFrame(rows[:, [0, 1, 2, 4]],
                                               columns=["alt", "Mach", "TRA", "T2"]))
    df = pd.DataFrame({"alt": rows[:, 0], "Mach": rows[:, 1], "TRA": rows[:, 2],
                       "SmLPC": ev["SmLPC"].to_numpy(), "ok": ev["converged"].to_numpy()})
    print(f"check of the model's own schedule: {df.ok.mean():.1%} of {len(df)} points "
          f"converged; lowest booster stall margin {df.SmLPC[df.ok].min():.2f} %\n")
    print("| alt ft | Mach | converged | lowest SmLPC % | at TRA |")
    print("|---|---|---|---|---|")
    for (alt, mach), g in df.groupby(["alt", "Mach"]):
        ok = g[g.ok]
        k = ok.SmLPC.idxmin() if len(ok) else None
        low = f"{ok.SmLPC.min():.2f} | {ok.TRA[k]:.0f}" if k is not None else "- | -"
        print(f"| {alt:.0f} | {mach:.3f} | {g.ok.sum()}/{len(g)} | {low} |")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="check the model's own schedule")
    ap.add_argument("--propose", action="store_true", help="design a schedule from the audit")
    args = ap.parse_args()
    check() if args.check else propose() if args.propose else audit()
