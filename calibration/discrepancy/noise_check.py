"""Check the noise model ``R`` on the data, channel by channel, before any threshold.

Every threshold of the loop assumes the whitened residual has unit variance where the model
is right. A model error (the very thing the loop looks for) also inflates the residual
variance, so the noise level is estimated from what a smooth model error cannot produce: the
differences of consecutive whitened residuals within a flight. With white noise of variance
``v`` and a model error that changes little between samples (at 0.1 Hz an effect varies over
tens of samples), ``E[(e_n - e_{n-1})^2] = 2 v``, so ``v_hat = mean(d^2) / 2`` (the von Neumann
(1941) mean-square-successive-difference estimator). For Gaussian noise the ``d_n`` are an
MA(1) sequence and ``Var(v_hat) = 3 v^2 / n_d``.

A channel is flagged when ``v_hat`` differs from 1 both significantly (``|z| > z_{alpha/2m}``,
Bonferroni over the ``m`` channels) and materially (its standard-deviation ratio outside
``1 +- TOLERANCE``). The loop then scales that channel's ``R`` by ``v_hat`` (and says so);
a channel with one sample per flight (no successive differences) is not checked.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import norm

TOLERANCE = 0.1


def successive_differences(e: np.ndarray, flight: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """``e_n - e_{n-1}`` (rows) where both samples belong to the same flight and converged."""
    same = (flight[1:] == flight[:-1]) & ok[1:] & ok[:-1]
    return (e[1:] - e[:-1])[same]


def check_noise(residuals: list, flights: list, oks: list, sensors, alpha: float = 0.01
                ) -> dict:
    """Per channel: ``std_ratio`` (estimated / documented noise std), ``z``, ``n``,
    ``flagged``; ``scale`` the per-channel factor to apply to sigma (1 where not flagged)."""
    d = [successive_differences(e, f, ok) for e, f, ok in zip(residuals, flights, oks,
                                                                 strict=True)]
    d = np.concatenate(d) if d else np.zeros((0, len(sensors)))
    n = len(d)
    m = len(sensors)
    out = {"channels": {}, "scale": np.ones(m), "n_differences": n, "alpha": alpha}
    if n < 10:
        out["note"] = "too few successive samples within flights to check the noise model"
        return out
    v = np.mean(d * d, axis=0) / 2.0
    z = (v - 1.0) / np.sqrt(3.0 / n)
    zc = norm.isf(alpha / (2 * m))
    for j, s in enumerate(sensors):
        ratio = float(np.sqrt(v[j]))
        flagged = bool(abs(z[j]) > zc and abs(ratio - 1.0) > TOLERANCE)
        out["channels"][s] = {"std_ratio": ratio, "z": float(z[j]), "flagged": flagged}
        if flagged:
            out["scale"][j] = ratio
    return out
