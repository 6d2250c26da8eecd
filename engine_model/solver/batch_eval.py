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
        if n <= CHUNK:  # one call: the filters' few dozen points per step take this path
            return self._call_padded(key, args, n)
        parts = [self._call_padded(key, [a[:, s0:s0 + CHUNK] for a in args],
                                   min(CHUNK, n - s0)) for s0 in range(0, n, CHUNK)]
        return [np.concatenate(outs, axis=1) for outs in zip(*parts, strict=True)]

    def _call_padded(self, key: str, args, m: int) -> list[np.ndarray]:
        """Function ``key`` on ``m`` points padded to their bucket; padded columns dropped."""
        nb = bucket(m)
        outs = self.mapped(key, nb)(*[pad_columns(a, nb) for a in args])
        if not isinstance(outs, (list, tuple)):
            outs = [outs]
        return [np.asarray(o)[:, : o.shape[1] // nb * m] for o in outs]


def pad_columns(a: np.ndarray, n: int) -> np.ndarray:
    """(k, m) -> (k, n) by repeating the last column (``n >= m``)."""
    m = a.shape[1]
    if m == n:
        return a
    out = np.empty((a.shape[0], n), dtype=a.dtype)
    out[:, :m] = a
    out[:, m:] = a[:, -1:]
    return out


def pad_rows(a: np.ndarray, n: int) -> np.ndarray:
    """(m, ...) -> (n, ...) by repeating the last row (``n >= m``)."""
    m = len(a)
    if m == n:
        return a
    out = np.empty((n, *a.shape[1:]), dtype=a.dtype)
    out[:m] = a
    out[m:] = a[-1:]
    return out
