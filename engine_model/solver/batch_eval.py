"""Evaluate CasADi functions of one point column-wise over a batch of points.

A CasADi ``Function`` of one point (``f(x, w, theta, p)``, each argument a column) is mapped
over ``N`` points with ``Function.map``. Building a map costs far more than calling it, so maps
are cached per batch size and batches are padded to a few sizes: multiples of 8 up to
:data:`SERIAL_MAX` points (mapped serially: for the few dozen points of a filter step starting
threads costs more than it saves), powers of two above it, and chunks of :data:`CHUNK` points
(mapped over threads) for large batches. Padding repeats the last point, and the padded
outputs are dropped.

Calls go through CasADi's zero-copy buffer interface (``Function.buffer``): the arguments are
handed over as numpy memory and the outputs are written into numpy arrays, instead of
converting every argument to a ``DM`` and every result back through Python lists (which cost
as much as the evaluation itself for the few hundred points of a filter step: about 40 % of an
``outputs`` call of 448 points, 30 % of a ``sens`` call of 200). The function evaluated is the
same, so the numbers are the same, bit for bit; a sparse output (the sensitivities have
structural zeros) is scattered into a dense array with zeros there, as ``DM.full()`` did.
"""

from __future__ import annotations

import numpy as np

CHUNK = 2048
SERIAL_MAX = 1024


def bucket(n: int) -> int:
    """The padded batch size for ``n`` points."""
    n = max(int(n), 1)
    if n <= SERIAL_MAX:
        return -(-n // 8) * 8
    return min(CHUNK, 1 << int(np.ceil(np.log2(n))))


class BatchEvaluator:
    """``evaluate(key, *args)`` calls function ``functions[key]`` on (k, N) column arrays and
    returns its outputs as (m, N) arrays (an output of m x q per point comes back as
    (m, q * N), points in column blocks, as CasADi's map lays it out)."""

    def __init__(self, functions: dict, n_threads: int = 1):
        self.functions = functions  # a mapping; it may build a function on first use
        self.n_threads = max(1, int(n_threads))
        self._maps: dict = {}

    def mapped(self, key: str, n: int):
        """Function ``key`` mapped over ``n`` points (cached)."""
        ck = (key, n)
        if ck not in self._maps:
            f = self.functions[key]
            if n > SERIAL_MAX and self.n_threads > 1:
                self._maps[ck] = f.map(n, "thread", self.n_threads)
            else:
                self._maps[ck] = f.map(n, "serial")
        return self._maps[ck]

    def __call__(self, key: str, *args: np.ndarray) -> list[np.ndarray]:
        n = args[0].shape[1]
        if n <= CHUNK:  # one call: the filters' few dozen points per step take this path
            return self._call_padded(key, args, n)
        parts = [self._call_padded(key, [a[:, s0:s0 + CHUNK] for a in args],
                                   min(CHUNK, n - s0)) for s0 in range(0, n, CHUNK)]
        return [np.concatenate(outs, axis=1) for outs in zip(*parts, strict=True)]

    def _call_padded(self, key: str, args, m: int) -> list[np.ndarray]:
        """Function ``key`` on ``m`` points padded to their bucket; padded columns dropped.

        A (k, n) argument is column-major in CasADi, i.e. the memory of an (n, k) C-ordered
        array: one point after the other. Output ``i`` of the mapped function holds its
        nonzeros point after point (``nnz`` each, in the per-point column-major order of
        :meth:`_scatter`), so it is read as (n, nnz), scattered to the dense (n, q * m_out)
        per-point blocks and returned as the (m_out, q * n) array ``DM.full()`` gave."""
        nb = bucket(m)
        f = self.mapped(key, nb)
        buf, run = f.buffer()
        ins = [np.ascontiguousarray(pad_rows(np.asarray(a, float).T, nb)) for a in args]
        for i, a in enumerate(ins):
            buf.set_arg(i, memoryview(a))
        raw = [np.empty((nb, f.nnz_out(i) // nb)) for i in range(f.n_out())]
        for i, r in enumerate(raw):
            buf.set_res(i, memoryview(r))
        run()
        outs = []
        for i, r in enumerate(raw):
            rows, cols = f.size_out(i)
            lin = self._scatter(key, i)
            if lin is None:  # dense: the raw memory is already the per-point blocks
                dense = r
            else:
                dense = np.zeros((nb, rows * cols // nb))
                dense[:, lin] = r
            full = np.ascontiguousarray(dense.reshape(cols, rows).T)  # (m_out, q * nb)
            outs.append(full[:, : cols // nb * m])
        return outs

    def _scatter(self, key: str, i: int) -> np.ndarray | None:
        """Positions of output ``i``'s nonzeros in one point's dense column-major block, or
        None when that output is dense (cached)."""
        ck = ("scatter", key, i)
        if ck not in self._maps:
            sp = self.functions[key].sparsity_out(i)
            if sp.is_dense():
                self._maps[ck] = None
            else:
                r, c = sp.get_triplet()
                self._maps[ck] = np.asarray(c, np.intp) * sp.size1() + np.asarray(r, np.intp)
        return self._maps[ck]


def pad_rows(a: np.ndarray, n: int) -> np.ndarray:
    """(m, ...) -> (n, ...) by repeating the last row (``n >= m``)."""
    m = len(a)
    if m == n:
        return a
    out = np.empty((n, *a.shape[1:]), dtype=a.dtype)
    out[:m] = a
    out[m:] = a[-1:]
    return out
