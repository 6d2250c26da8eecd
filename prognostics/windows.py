"""Sliding windows over the scaled rows, as strided views: no copy per window.

The paper (Sec. 4.2): "the first input sample to the network takes measurements from timestamps
1-50, the second 2-51, the third 3-52, and so on for each unit", window length
``N_tw = 50``, stride 1. The input of window ``i`` of a segment starting at row ``a`` is rows
``a + s i .. a + s i + L - 1`` (``s`` the stride, ``L`` the length) and its target is the RUL of
its **last** row (the prediction is made with the data seen so far).

- **Where windows are cut.** Only inside a *segment*: a run of consecutive rows of one unit and
  one role (:func:`splits.segments`), so no window spans two units, a training and a validation
  flight, or a development and a test unit.
- **Views, not copies.** All scaled rows live in one C-contiguous ``(N, k)`` float32 tensor
  ``base``; ``base.unfold(0, L, 1)`` is a ``(N - L + 1, k, L)`` view of it (channels, then
  time, as ``Conv1d`` indexes them), and a window set is that view plus the int64 start row
  of each window. A mini-batch gathers its windows (one ``(B, k, L)`` copy of ``B`` windows,
  stored time-major); the window set itself never holds more than ``base``, whatever ``L``.
- **Short segments.** A segment of ``n < L`` rows is left-padded with ``L - n`` copies of its
  first row (the engine as first seen, held: a plausible operating point, unlike zeros after
  scaling, which would be a fictitious mid-range condition) and gives exactly one window, whose
  target is the RUL of its last real row. Only then is ``base`` a (single, whole) copy of the
  rows with the pads inserted.
- **FNN.** The paper's FNN maps one time step to RUL; it is the case ``L = 1``, where a
  batch is ``base[starts]`` with shape ``(B, k)``.
- Samples before the first full window of a segment (its first ``L - 1`` rows) have no
  prediction and are left out of the metrics, as in the paper's windowed test set.
- **Every row** (``pad_all=True``, the flight-level models of :mod:`.flights`): every segment
  is left-padded with ``L - 1`` copies of its first row, so that each row ends a window and
  gets a prediction (a window over flights is long compared with a unit's life: dropping its
  first ``L - 1`` flights would drop a third of a unit). A flight model's segments are whole
  units, as at prediction: each window takes the role of its last flight
  (:func:`prognostics.training.prepare`), so a training window that follows a validation
  flight reads that flight's inputs, not a padded history.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np
import torch

from engine_model.validation import InputError


@dataclass
class Windows:
    """Windows of ``length`` rows over ``base`` starting at ``starts``.

    ``rows`` is the index, in the caller's table, of each window's last row; ``target`` its
    RUL (float32, or None when the caller has no target).
    """

    base: torch.Tensor
    starts: torch.Tensor
    length: int
    rows: np.ndarray
    target: torch.Tensor | None = None

    def __len__(self) -> int:
        return int(self.starts.numel())

    @property
    def n_features(self) -> int:
        return int(self.base.shape[1])

    def view(self) -> torch.Tensor:
        """All windows of ``base`` as one strided ``(N - L + 1, k, L)`` view (no copy)."""
        return self.base.unfold(0, self.length, 1)

    def batch(self, index: torch.Tensor) -> torch.Tensor:
        """The inputs of windows ``index``: a ``(B, k, L)`` copy of those windows whose memory
        is ``(B, L, k)`` (each window's rows as in ``base``: the gather copies whole rows, and
        it is the layout the channels-last convolution of
        :class:`prognostics.models.SameConv1d` reads without a copy), or ``(B, k)`` when
        ``L == 1``."""
        s = self.starts[index]
        if self.length == 1:
            return self.base[s]
        return self.view().transpose(1, 2)[s].contiguous().transpose(1, 2)

    def subset(self, pick: np.ndarray) -> Windows:
        """The windows where the boolean ``pick`` (one per window) is true, over the same
        ``base``."""
        keep = torch.as_tensor(np.flatnonzero(pick), dtype=torch.int64)
        tgt = None if self.target is None else self.target[keep]
        return Windows(self.base, self.starts[keep], self.length, self.rows[np.asarray(pick)],
                       tgt)

    def to(self, device) -> Windows:
        """The same windows on ``device`` (the base moves once; windows stay views)."""
        tgt = None if self.target is None else self.target.to(device)
        return Windows(self.base.to(device), self.starts.to(device), self.length, self.rows,
                       tgt)


def memory_bytes() -> int:
    """The machine's physical memory [bytes] (POSIX ``sysconf``; 64 GiB where unknown)."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):  # pragma: no cover - not POSIX
        return 64 * 2**30


def make_windows(x: np.ndarray, seg_starts: np.ndarray, seg_ends: np.ndarray, length: int,
                 stride: int = 1, target: np.ndarray | None = None,
                 pad_all: bool = False) -> Windows:
    """Windows of ``length`` rows with step ``stride`` inside each segment
    ``[seg_starts[i], seg_ends[i])`` of the scaled rows ``x`` (N, k) (module docstring;
    ``pad_all``: every segment left-padded so that every row ends a window).

    Without short segments, ``base`` shares memory with ``x`` (pass a C-contiguous float32
    array, as :meth:`MinMaxScaler.transform` returns). Vectorised: no Python loop per window
    or per segment.
    """
    if length < 1 or stride < 1:
        raise InputError(f"window length and stride must be >= 1, got {length} and {stride}")
    x = np.ascontiguousarray(x, dtype=np.float32)
    n_rows = len(x)
    a = np.asarray(seg_starts, dtype=np.int64)
    b = np.asarray(seg_ends, dtype=np.int64)
    if np.any(b <= a) or np.any(a < 0) or np.any(b > n_rows):
        raise InputError("windows: empty or out-of-range segment")
    pad = np.full(len(a), length - 1, np.int64) if pad_all else np.maximum(length - (b - a), 0)
    need = (n_rows + int(pad.sum())) * x.shape[1] * 4 if x.ndim == 2 else 0
    if pad.any() and need > memory_bytes() // 2:
        raise InputError(f"windows of {length} rows over {len(a)} segment(s) of at most "
                         f"{int((b - a).max())} rows would need {need / 2**30:,.0f} GiB of "
                         f"padding (this machine has {memory_bytes() / 2**30:,.0f} GiB): the "
                         "window is far longer than the data")
    if pad.any():
        repeats = np.ones(n_rows, dtype=np.int64)
        np.add.at(repeats, a, pad)
        src = np.repeat(np.arange(n_rows), repeats)
        new_pos = np.cumsum(repeats) - 1  # position of original row i in the padded base
        base_np = x[src]
        a_new = new_pos[a] - pad
        b_new = new_pos[b - 1] + 1
    else:
        src = None
        base_np = x
        a_new, b_new = a, b
    n_win = (b_new - a_new - length) // stride + 1
    total = int(n_win.sum())
    seg = np.repeat(np.arange(len(a_new)), n_win)
    first = np.cumsum(n_win) - n_win
    starts = a_new[seg] + stride * (np.arange(total) - first[seg])
    last = starts + length - 1
    rows = last if src is None else src[last]
    tgt = None
    if target is not None:
        tgt = torch.from_numpy(np.ascontiguousarray(np.asarray(target, np.float32)[rows]))
    return Windows(torch.from_numpy(base_np), torch.from_numpy(starts), length, rows, tgt)
