"""Health signatures: how each health parameter moves the gas-path channels.

:func:`signature_table` lowers every health parameter (``THETA_NAMES``) by ``DELTA`` at fixed TRA
at sea-level take-off, climb and cruise (:data:`SIGNATURE_POINTS`) and returns the change of
each channel of :data:`SIGNATURE_CHANNELS` (N-CMAPSS units; ``Wf`` in pph), the channel noise
sigma at each point (:mod:`sensor_noise`) and the sign flips: a (parameter, channel) whose
change exceeds sigma at two points with opposite signs. A diagnostic that reads a channel's
direction as a fault's fingerprint relies on there being none.
"""

from __future__ import annotations

import numpy as np

from engine_model.channels import THETA_NAMES
from engine_model.physics.atmosphere import t2_from_flight
from engine_model.simulator.sensor_noise import SIGMA_REL
from engine_model.units import R_PER_K

SIGNATURE_CHANNELS = ("T24", "T30", "T48", "T50", "P30", "Nc", "Wf")
SIGNATURE_POINTS = {
    "SLS": (0.0, 0.0, 100.0),  # take-off
    "climb": (20000.0, 0.7, 90.0),
    "cruise": (35000.0, 0.8, 70.0),
}
DELTA = -0.02
PPH_PER_PPS = 3600.0


def signature_table(model, delta: float = DELTA):
    """``(table, sigma, flips)``: ``table[theta][channel][point]`` the change of the channel
    when ``theta`` is lowered by ``-delta``, ``sigma[channel][point]`` the channel's noise
    standard deviation there, ``flips`` the set of ``(theta, channel)`` sign flips beyond
    sigma."""
    pts = list(SIGNATURE_POINTS.values())
    n_th = len(THETA_NAMES)
    w = np.array([[a, m, t, float(t2_from_flight(a, m, 0.0)) * R_PER_K] for a, m, t in pts])
    ww = np.repeat(w, n_th + 1, axis=0)
    th = np.tile(np.vstack([np.zeros(n_th), delta * np.eye(n_th)]), (len(pts), 1))
    ev = model.evaluate(ww, th)
    if not ev.converged.all():
        raise RuntimeError("signature points did not converge")
    y = ev[list(SIGNATURE_CHANNELS)].to_numpy().reshape(len(pts), n_th + 1, -1)
    scale = np.array([PPH_PER_PPS if c == "Wf" else 1.0 for c in SIGNATURE_CHANNELS])
    y = y * scale
    d = y[:, 1:, :] - y[:, :1, :]  # (point, theta, channel)
    sig = y[:, 0, :] * np.array([SIGMA_REL[c] for c in SIGNATURE_CHANNELS])
    labels = list(SIGNATURE_POINTS)
    table = {t: {c: {p: float(d[i, j, k]) for i, p in enumerate(labels)}
                 for k, c in enumerate(SIGNATURE_CHANNELS)} for j, t in enumerate(THETA_NAMES)}
    sigma = {c: {p: float(sig[i, k]) for i, p in enumerate(labels)}
             for k, c in enumerate(SIGNATURE_CHANNELS)}
    flips = set()
    for j, t in enumerate(THETA_NAMES):
        for k, c in enumerate(SIGNATURE_CHANNELS):
            big = np.abs(d[:, j, k]) > sig[:, k]
            signs = set(np.sign(d[big, j, k]).tolist())
            if len(signs) > 1:
                flips.add((t, c))
    return table, sigma, flips
