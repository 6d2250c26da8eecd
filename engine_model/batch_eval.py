"""Evaluate CasADi functions of one point column-wise over a batch of points.

A CasADi ``Function`` of one point (``f(x, w, theta, p)``, each argument a column) is mapped
over ``N`` points with ``Function.map``. Building a map costs far more than calling it, so maps
are cached per batch size and batches are padded to a few sizes: multiples of 8 up to
:data:`SERIAL_MAX` points (mapped serially: for the few dozen points of a filter step starting
threads costs more than it saves), powers of two above it, and chunks of :data:`CHUNK` points
(mapped over threads) for large batches. Padding repeats the last point, and the padded
outputs are dropped.
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
        self.functions = dict(functions)
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
        results: list[list[np.ndarray]] | None = None
        for s0 in range(0, n, CHUNK):
            s1 = min(n, s0 + CHUNK)
            m = s1 - s0
            nb = bucket(m)
            padded = [pad_columns(a[:, s0:s1], nb) for a in args]
            outs = self.mapped(key, nb)(*padded)
            if not isinstance(outs, (list, tuple)):
                outs = [outs]
            outs = [np.asarray(o)[:, : o.shape[1] // nb * m] for o in outs]
            if results is None:
                results = [[o] for o in outs]
            else:
                for lst, o in zip(results, outs, strict=True):
                    lst.append(o)
        return [np.concatenate(lst, axis=1) for lst in results]


def pad_columns(a: np.ndarray, n: int) -> np.ndarray:
    """(k, m) -> (k, n) by repeating the last column (``n >= m``)."""
    m = a.shape[1]
    if m == n:
        return a
    return np.concatenate([a, np.repeat(a[:, -1:], n - m, axis=1)], axis=1)


def pad_rows(a: np.ndarray, n: int) -> np.ndarray:
    """(m, ...) -> (n, ...) by repeating the last row (``n >= m``)."""
    m = len(a)
    if m == n:
        return a
    return np.concatenate([a, np.repeat(a[-1:], n - m, axis=0)], axis=0)
