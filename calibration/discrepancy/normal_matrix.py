"""The Gauss-Newton matrix of the null fit, kept in its structure.

Over ``[Theta (every unit, every cycle), phi]`` the matrix is *bordered block-diagonal*: one
block per unit (its cycles' data blocks plus the random-walk prior, block-tridiagonal in the
cycles), a border per unit (how its theta and phi interact) and the dense ``phi`` block::

    H = [ H_1            B_1 ]
        [      ...       ... ]
        [           H_U  B_U ]
        [ B_1^T ... B_U^T  D ]

Stored dense, 85 engines x 40 cycles x 3 parameters is a 10,200-square matrix (830 MB) that
every factorisation visits in full (the cost grows as its cube). Kept as blocks, a solve
with the theta of every unit and any subset ``free`` of ``phi`` is one Cholesky factorisation
per unit and one of the Schur complement on ``phi[free]`` (Triggs et al., "Bundle
adjustment - a modern synthesis", 2000, sec. 6.1): the cost is linear in the number of
units. :meth:`NormalMatrix.dense` gives the full matrix where a small problem wants it.

Each solve scales the matrix to unit diagonal and adds ``1e-12`` to it (as the dense code
does), so a parameter the data barely see does not make the factorisation fail.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve

JITTER = 1e-12


@dataclass
class NormalMatrix:
    """``blocks[i]`` (n_i, n_i) unit ``i``'s theta block (data and prior), ``borders[i]``
    (n_i, n_phi), ``D`` (n_phi, n_phi); ``offsets`` the units' starts in the theta vector."""

    blocks: list
    borders: list
    D: np.ndarray
    offsets: np.ndarray

    @property
    def n_theta(self) -> int:
        return int(self.offsets[-1])

    @property
    def n_phi(self) -> int:
        return len(self.D)

    def dense(self) -> np.ndarray:
        nt, n = self.n_theta, self.n_theta + self.n_phi
        H = np.zeros((n, n))
        for i, (blk, bor) in enumerate(zip(self.blocks, self.borders, strict=True)):
            sl = slice(self.offsets[i], self.offsets[i + 1])
            H[sl, sl] = blk
            H[sl, nt:] = bor
            H[nt:, sl] = bor.T
        H[nt:, nt:] = self.D
        return H

    def diag(self) -> np.ndarray:
        return np.concatenate([*(np.diag(b) for b in self.blocks), np.diag(self.D)])

    def theta_columns(self, idx) -> np.ndarray:
        """``H[theta, nt + idx]``: the borders' columns ``idx`` stacked over units."""
        return np.concatenate([b[:, idx] for b in self.borders], axis=0)

    def solve(self, free, rhs, fixed=None) -> np.ndarray:
        """``x`` with ``H_SS x = rhs`` over ``S = [every theta, phi[free]]`` (``rhs`` (n_S,)
        or (n_S, r)). ``fixed`` (n_S,) bool: those coordinates are held at ``rhs``'s value
        (their rows become the identity; their columns move to the right-hand side)."""
        free = np.asarray(free, int)
        nt = self.n_theta
        vec = rhs.ndim == 1
        R = rhs.reshape(len(rhs), -1).astype(float)
        fx = np.zeros(nt + len(free), bool) if fixed is None else np.asarray(fixed, bool)
        xf_fixed = np.where(fx[:, None], R, 0.0)  # values of the fixed coordinates
        Df = self.D[np.ix_(free, free)].copy()
        rf = R[nt:].copy()
        # phi[free] coordinates held: their columns to the right-hand side
        pf = fx[nt:]
        rf -= Df[:, pf] @ xf_fixed[nt:][pf]
        Ys = []
        Sf = Df
        for i, (blk, bor) in enumerate(zip(self.blocks, self.borders, strict=True)):
            sl = slice(self.offsets[i], self.offsets[i + 1])
            H = blk.copy()
            Bf = bor[:, free].copy()
            r = R[sl].copy()
            f = fx[sl]
            r -= H[:, f] @ xf_fixed[sl][f] + Bf[:, pf] @ xf_fixed[nt:][pf]
            rf -= Bf[f].T @ xf_fixed[sl][f]
            if f.any():
                H[f, :] = 0.0
                H[:, f] = 0.0
                H[f, f] = 1.0
                Bf[f, :] = 0.0
                r[f] = xf_fixed[sl][f]
            Bf[:, pf] = 0.0
            d = np.sqrt(np.maximum(np.diag(H), 1e-300))
            fac = cho_factor(H / np.outer(d, d) + JITTER * np.eye(len(H)))
            Y = cho_solve(fac, np.column_stack([Bf, r]) / d[:, None]) / d[:, None]
            Ys.append(Y)
            Sf = Sf - Bf.T @ Y[:, :len(free)]
            rf -= Bf.T @ Y[:, len(free):]
        if len(free):
            Sf[pf, :] = 0.0
            Sf[:, pf] = 0.0
            Sf[pf, pf] = 1.0
            rf[pf] = xf_fixed[nt:][pf]
            ds = np.sqrt(np.maximum(np.abs(np.diag(Sf)), 1e-300))
            xf = np.linalg.lstsq(Sf / np.outer(ds, ds) + JITTER * np.eye(len(Sf)),
                                 rf / ds[:, None], rcond=None)[0] / ds[:, None]
        else:
            xf = np.zeros((0, R.shape[1]))
        out = np.zeros_like(R)
        for i, Y in enumerate(Ys):
            sl = slice(self.offsets[i], self.offsets[i + 1])
            out[sl] = Y[:, len(free):] - Y[:, :len(free)] @ xf
        out[nt:] = xf
        return out[:, 0] if vec else out

    def schur(self, free) -> np.ndarray:
        """``D_ff - sum_u B_uf^T H_u^-1 B_uf``: the information on ``phi[free]`` with every
        theta marginalised out (its inverse is the covariance of ``phi[free]``)."""
        free = np.asarray(free, int)
        S = self.D[np.ix_(free, free)].copy()
        for blk, bor in zip(self.blocks, self.borders, strict=True):
            d = np.sqrt(np.maximum(np.diag(blk), 1e-300))
            fac = cho_factor(blk / np.outer(d, d) + JITTER * np.eye(len(blk)))
            Bf = bor[:, free]
            S -= Bf.T @ (cho_solve(fac, Bf / d[:, None]) / d[:, None])
        return 0.5 * (S + S.T)
