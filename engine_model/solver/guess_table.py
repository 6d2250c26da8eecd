"""Starting guesses of the steady-state unknowns: a table over (T2, PCNfR_dmd, Mach), in the
controller's ground-idle and flight-idle modes.

By similarity the corrected operating point of a turbofan depends mainly on the demanded
corrected fan speed and the flight Mach number; T2 enters through the gas properties. The
table holds the unknowns at sea-level pressure on a grid of those three (T40 stored as T40/T2)
plus ``dx*/dtheta`` at every node, and a guess is the trilinear interpolation of the nodes
plus their first-order health correction ``dx*/dtheta . theta`` (linear extrapolation in T2
outside the nodes). Without Reynolds effects the corrected operating point does not depend on
pressure, so one altitude serves all - per controller mode: the minimum core speed differs on
the ground and in flight (:mod:`schedule`), so the table is filled at sea level (ground mode
below Mach 0.05-0.15) and at 10,000 ft (flight mode at every Mach), and a guess blends the two
with the controller's own altitude weight.

The table is filled by continuation when a model is first built and cached on disk next to
the compiled code, keyed by a hash of the residual system (a changed model rebuilds it).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

from engine_model.runtime.atomic import atomic_output
from engine_model.runtime.build_lock import build_lock
from engine_model.runtime.ownership import OWNED_FILE
from engine_model.units import R_PER_K

TABLE_PCT = np.linspace(24.0, 104.0, 41)  # from below ground idle (25 %) to maximum
TABLE_MACH = np.linspace(0.0, 0.9, 10)
TABLE_T2 = (540.0, 470.0, 400.0)  # degR, descending
TABLE_ALT = (0.0, 10000.0)  # ft: the ground-idle and the flight-idle controller modes
I_T40 = 4  # position of T40 among the unknowns (stored divided by T2)
_CHUNK = 4096  # points per block of the lookup


class GuessTable:
    """Tabulated unknowns ``table`` (n_T2, n_pct, n_Mach, n_x) and ``dth`` (..., n_x, n_theta)
    with the design T40 [K] used to scale T40 and the fan-speed schedule of the design."""

    def __init__(self, table: np.ndarray, dth: np.ndarray, t40_des_k: float,
                 nf_demand_pct: Callable[[np.ndarray], np.ndarray],
                 flight_weight: Callable[[np.ndarray], np.ndarray]):
        self.table = table
        self.dth = dth
        self.t40_des_r = t40_des_k * R_PER_K
        self.nf_demand_pct = nf_demand_pct
        self.flight_weight = flight_weight
        # the nodes as rows (mode, T2, pct, Mach) of [x] and of [x | dx/dtheta]: the health
        # correction is linear in the node values, so it interpolates with them
        n_x = table.shape[-1]
        self._rows_x = np.ascontiguousarray(table.reshape(-1, n_x))
        self._rows_th = np.hstack([self._rows_x, dth.reshape(len(self._rows_x), -1)])

    # ------------------------------------------------------------------ building
    @classmethod
    def build(cls, solve_from: Callable, continuation: Callable, dx_dtheta: Callable,
              tra_from_pct: Callable, n_theta: int, t40_des_k: float,
              nf_demand_pct: Callable, x_design: np.ndarray,
              flight_weight: Callable) -> GuessTable:
        """Fill the table by continuation over (T2, PCNfR_dmd, Mach): from the design point at
        each T2, along Mach, then along the fan speed up and down from 100 %.

        ``solve_from(w, theta, x0, max_iter=...) -> SolveResult`` (plain Newton, no retry),
        ``continuation(w_target, x_start, theta) -> SolveResult``, ``dx_dtheta(x, w, theta)
        -> (N, n_x, n_theta)``, ``tra_from_pct(pct) -> TRA``."""
        n_t, n_p, n_m, n_x = len(TABLE_T2), len(TABLE_PCT), len(TABLE_MACH), len(x_design)
        n_a = len(TABLE_ALT)
        table = np.zeros((n_a, n_t, n_p, n_m, n_x))
        i_des = int(np.argmin(np.abs(TABLE_PCT - 100.0)))
        order = list(range(i_des, n_p)) + list(range(i_des - 1, -1, -1))
        zeros = np.zeros(n_theta)
        for ia, alt in enumerate(TABLE_ALT):
            x_node = np.array(x_design, float)
            for it2, T2 in enumerate(TABLE_T2):
                r = continuation(np.array([alt, 0.0, 100.0, T2]), x_node, zeros)
                x_node = r.x[0]
                x_prev_col = x_node
                for j, mach in enumerate(TABLE_MACH):
                    x_prev = x_prev_col
                    for k, i in enumerate(order):
                        if i == i_des - 1:
                            x_prev = table[ia, it2, i_des, j]
                        w = np.array([[alt, mach, tra_from_pct(TABLE_PCT[i]), T2]])
                        r = solve_from(w, zeros[None, :], x_prev[None, :], max_iter=60)
                        if not r.converged[0]:
                            r = continuation(w[0], x_prev, zeros)
                        table[ia, it2, i, j] = r.x[0]
                        x_prev = r.x[0]
                        if k == 0:
                            x_prev_col = r.x[0]
        ww = np.array([[alt, mach, tra_from_pct(pct), T2] for alt in TABLE_ALT for T2 in TABLE_T2
                       for pct in TABLE_PCT for mach in TABLE_MACH])
        dxdth = dx_dtheta(table.reshape(-1, n_x), ww, np.zeros((len(ww), n_theta)))
        dxdth = dxdth.reshape(n_a, n_t, n_p, n_m, n_x, n_theta)
        scale = t40_des_k * R_PER_K / np.asarray(TABLE_T2)[None, :, None, None]
        dxdth[..., I_T40, :] *= scale[..., None]
        table[..., I_T40] *= scale  # store T40/T2
        return cls(table, dxdth, t40_des_k, nf_demand_pct, flight_weight)

    @classmethod
    def load_or_build(cls, path: Path, build: Callable[[], GuessTable], t40_des_k: float,
                      nf_demand_pct: Callable, flight_weight: Callable) -> GuessTable:
        """The table cached at ``path`` (an ``.npz``), else ``build()`` and cache it (written
        atomically, :mod:`engine_model.runtime.atomic`: concurrent processes never read half a
        file). Built under :func:`~engine_model.runtime.build_lock.build_lock`: of several
        processes that miss it at once, one builds it and the others wait and load it."""

        def load() -> GuessTable | None:
            if not path.exists():
                return None
            try:
                z = np.load(path)
                return cls(z["table"], z["dth"], t40_des_k, nf_demand_pct, flight_weight)
            except (OSError, KeyError, ValueError):
                return None  # unreadable: built again and replaced

        tab = load()
        if tab is not None:
            return tab
        with build_lock(path):
            tab = load()  # built meanwhile by the process that held the lock
            if tab is None:
                tab = build()
                with atomic_output(path, OWNED_FILE) as staged, open(staged, "wb") as fh:
                    np.savez(fh, table=tab.table, dth=tab.dth)
        return tab

    @staticmethod
    def cache_key(serialized_residual: str) -> str:
        """Hash of the residual system and of the table's grid (either changes the table)."""
        grid = repr((TABLE_ALT, TABLE_T2, TABLE_PCT.tolist(), TABLE_MACH.tolist()))
        return hashlib.sha256((serialized_residual + grid).encode()).hexdigest()[:16]

    # ------------------------------------------------------------------ lookup
    def __call__(self, w: np.ndarray, theta: np.ndarray | None = None) -> np.ndarray:
        """Starting unknowns (N, n_x) for operating points ``w`` (N, 4) and health ``theta``
        (N, n_theta) or None (new engine)."""
        w = np.atleast_2d(np.asarray(w, float))
        pct = self.nf_demand_pct(w[:, 2])
        t2n = np.asarray(TABLE_T2)
        coords = [
            np.clip((w[:, 3] - t2n[0]) / (t2n[1] - t2n[0]), -1.0, len(t2n) - 1 + 1.0),
            np.clip((pct - TABLE_PCT[0]) / (TABLE_PCT[1] - TABLE_PCT[0]), 0,
                    len(TABLE_PCT) - 1),
            np.clip(w[:, 1] / (TABLE_MACH[1] - TABLE_MACH[0]), 0, len(TABLE_MACH) - 1),
        ]
        sizes = (len(t2n), len(TABLE_PCT), len(TABLE_MACH))
        n_x = self.table.shape[-1]
        # nodes flattened to rows [x | dx/dtheta]: one gather per corner of the cell
        rows = self._rows_x if theta is None else self._rows_th
        flat = np.zeros(len(w), np.int64)
        lo, hi = [], []
        for c, nmax in zip(coords, sizes, strict=True):
            i = np.clip(np.floor(c).astype(np.int64), 0, nmax - 2)
            flat = flat * nmax + i
            f = c - i
            lo.append(1.0 - f)
            hi.append(f)
        strides = np.cumprod((1,) + sizes[:0:-1])[::-1]  # row offsets of (T2, pct, Mach)
        wa = np.asarray(self.flight_weight(w[:, 0]), float)
        n_nodes = int(np.prod(sizes))
        corners = []  # (mode, bits, row offset) of the 16 corners of a cell in both modes
        for mode in (0, 1):
            for corner in range(8):
                bits = [(corner >> k) & 1 for k in range(3)]
                corners.append((mode, bits, mode * n_nodes + int(np.dot(bits, strides))))
        x = np.empty((len(w), n_x))
        th = None if theta is None else np.asarray(theta, float)
        for a in range(0, len(w), _CHUNK):  # chunks keep the gathered rows in cache
            sl = slice(a, a + _CHUNK)
            acc = np.zeros((len(flat[sl]), rows.shape[1]))
            for mode, bits, off in corners:
                wgt = wa[sl] if mode else 1.0 - wa[sl]
                for b, f_lo, f_hi in zip(bits, lo, hi, strict=True):
                    wgt = wgt * (f_hi[sl] if b else f_lo[sl])
                acc += wgt[:, None] * rows[flat[sl] + off]
            x[sl] = acc[:, :n_x]
            if th is not None:
                x[sl] += np.einsum("nkt,nt->nk", acc[:, n_x:].reshape(len(acc), n_x, -1), th[sl])
        x[:, I_T40] *= w[:, 3] / self.t40_des_r
        return x
