"""The fleet fit with the model's own error shared by an operating condition
(``FleetData.shared_error``, calibration.adaptation.fleet_fit) against the closed form: on a
model linear in the engines' health and the shared parameters, the fit's optimum and its
posterior covariance are those of generalised least squares whose noise covariance couples
the samples of one condition and channel (``noise^2 I + s^2 1 1^T``, Kennedy & O'Hagan's
discrepancy integrated out); without it, those of independent samples with the combined
std. No engine model is compiled here."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pandas as pd
import pytest

from calibration.adaptation.data import fleet_data
from calibration.adaptation.fleet_fit import S_THETA, FleetData, Shared, fit_fleet
from engine_model.channels import THETA_NAMES, W_NAMES
from engine_model.validation import InputError

K = len(THETA_NAMES)


class LinearModel:
    """``y = a(w) + A(w) delta + B(w) phi``, the sensitivities fixed per operating condition
    (the condition is read from ``w``'s first column), the shape of
    :class:`calibration.discrepancy.candidates.CandidateModel`'s ``evaluate``."""

    def __init__(self, conditions, m, n_phi, rng):
        self.n_phi = n_phi
        self.a = {c: rng.normal(size=m) for c in conditions}
        self.A = {c: rng.normal(size=(m, K)) for c in conditions}
        self.B = {c: rng.normal(size=(m, n_phi)) for c in conditions}

    def evaluate(self, w, theta, channels, phi, derivatives=False, x0=None, est_idx=None):
        cond = w[:, 0].astype(int)
        A = np.stack([self.A[c] for c in cond])
        B = np.stack([self.B[c] for c in cond])
        a = np.stack([self.a[c] for c in cond])
        y = a + np.einsum("nmk,nk->nm", A, theta) + B @ phi
        return SimpleNamespace(y=y, d_theta=A, d_phi=B, converged=np.ones(len(w), bool),
                               x=None)


def fleet(shared_error, seed=0, units=6, per_condition=4, conditions=(1, 2, 3), m=4,
          n_phi=3):
    rng = np.random.default_rng(seed)
    model = LinearModel(conditions, m, n_phi, rng)
    unit = np.repeat(np.arange(units), per_condition * len(conditions))
    cond = np.tile(np.repeat(conditions, per_condition), units)
    n = len(unit)
    w = np.zeros((n, 4))
    w[:, 0] = cond
    delta = rng.normal(scale=S_THETA, size=(units, K))
    phi = np.array([0.02, -0.01, 0.015])
    noise = rng.uniform(0.01, 0.03, size=(n, m))
    model_sd = np.stack([np.full(m, 0.02 * c) for c in cond])  # the same within a condition
    offset = {c: rng.normal(scale=0.02 * c, size=m) for c in conditions}
    y = model.evaluate(w, delta[unit], None, phi).y \
        + np.stack([offset[c] for c in cond]) + rng.normal(size=(n, m)) * noise
    sigma = np.sqrt(noise ** 2 + model_sd ** 2)
    data = FleetData(w, y, sigma, unit, tuple(range(units)), cond, np.zeros(n),
                     tuple(f"c{j}" for j in range(m)), model_sd, shared_error)
    prior = np.array([0.05, 0.04, 0.03])
    shared = Shared(np.arange(n_phi), prior, np.full(n_phi, -1.0), np.full(n_phi, 1.0))
    return model, data, shared, noise


def closed_form(model, data, shared, noise, coupled):
    """The posterior mode and covariance of ``[delta_1..delta_U, phi]`` by generalised least
    squares with the Gaussian priors."""
    n, m = data.y.shape
    U, p = data.n_units, len(shared.free)
    ev = model.evaluate(data.w, np.zeros((n, K)), None, np.zeros(model.n_phi))
    J = np.zeros((n * m, U * K + p))
    for i in range(n):
        u = data.unit[i]
        J[i * m:(i + 1) * m, u * K:(u + 1) * K] = ev.d_theta[i]
        J[i * m:(i + 1) * m, U * K:] = ev.d_phi[i]
    r = (data.y - ev.y).ravel()
    if coupled:
        cov = np.diag((noise ** 2).ravel())
        flat_cond = np.repeat(data.condition, m)
        flat_chan = np.tile(np.arange(m), n)
        sd = data.model_sd.ravel()
        same = (flat_cond[:, None] == flat_cond[None]) & (flat_chan[:, None] == flat_chan[None])
        cov = cov + same * np.outer(sd, sd)
    else:
        cov = np.diag((data.sigma ** 2).ravel())
    P = np.diag(np.concatenate([np.full(U * K, 1 / S_THETA ** 2), 1 / shared.prior ** 2]))
    H = J.T @ np.linalg.solve(cov, J) + P
    x = np.linalg.solve(H, J.T @ np.linalg.solve(cov, r))
    post = np.linalg.inv(H)
    return x[:U * K].reshape(U, K), x[U * K:], post[U * K:, U * K:]


@pytest.mark.parametrize("shared_error", [True, False])
def test_the_fleet_fit_is_generalised_least_squares_with_the_shared_error_integrated_out(
        shared_error):
    model, data, shared, noise = fleet(shared_error)
    fit = fit_fleet(model, data, shared, max_iter=100)
    delta, phi, cov = closed_form(model, data, shared, noise, coupled=shared_error)
    np.testing.assert_allclose(fit.phi, phi, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(fit.delta, delta, rtol=1e-5, atol=1e-9)
    np.testing.assert_allclose(fit.cov, cov, rtol=1e-6)
    # the residual is the model's own (no offset), whitened by the combined std
    np.testing.assert_allclose(fit.residual, (data.y - fit.prediction) / data.sigma)
    if shared_error:
        assert fit.discrepancy.shape == (3, data.y.shape[1])
        assert fit.border_cov.shape == (3 + fit.discrepancy.size,) * 2
    else:
        assert fit.discrepancy is None


def test_shared_and_independent_differ_where_the_model_error_dominates():
    """With four samples a condition and the model error comparable to the noise, counting
    it four times as independent shrinks phi's posterior std below what the data support."""
    model, data, shared, _ = fleet(True)
    shared_fit = fit_fleet(model, data, shared, max_iter=100)
    indep = fit_fleet(model, FleetData(**{**vars(data), "shared_error": False}), shared,
                      max_iter=100)
    assert np.all(shared_fit.std > 1.2 * indep.std), (shared_fit.std, indep.std)


def test_sharing_a_model_error_of_zero_is_refused():
    rows = [{"unit": u, "cycle": c, "condition": k, **dict.fromkeys(W_NAMES, 0.0),
             "T30": 1500.0 + u + c} for u in (1, 2) for c in (1, 2) for k in (1, 2)]
    df = pd.DataFrame(rows)
    with pytest.raises(InputError, match="model-error-shared: the model error is 0"):
        fleet_data(df, ("T30",), model_error=0.0, shared_model_error=True)
    data, _ = fleet_data(df, ("T30",), model_error=0.001, shared_model_error=True)
    assert data.shared_error and data.subset(data.unit == 0).shared_error


def test_a_held_out_conditions_prediction_std_is_the_closed_forms():
    """``mean_prediction_std`` of a condition the fit did not see, the model error shared:
    the posterior of every engine's health and of phi (the fitted offsets of the other
    conditions integrated out), the noise averaged over the samples, and the held-out
    condition's own model error, which does not average."""
    from calibration.adaptation.fleet_fit import evaluate, mean_prediction_std

    model, data, shared, noise = fleet(True)
    held = data.condition == 3
    train, test = data.subset(~held), data.subset(held)
    fit = fit_fleet(model, train, shared, max_iter=100)
    ev, _, ok = evaluate(model, test, fit.delta, fit.phi, derivatives=True)
    std = mean_prediction_std(fit, ev, test, np.arange(test.n_units), ok)

    n, m = test.y.shape
    U, p = train.n_units, len(shared.free)
    # the joint posterior covariance of [delta_1..delta_U, phi] from the training samples
    tr_noise = noise[~held]
    ev_tr = model.evaluate(train.w, np.zeros((len(train.y), K)), None, np.zeros(model.n_phi))
    J = np.zeros((train.y.size, U * K + p))
    for i in range(len(train.y)):
        u = train.unit[i]
        J[i * m:(i + 1) * m, u * K:(u + 1) * K] = ev_tr.d_theta[i]
        J[i * m:(i + 1) * m, U * K:] = ev_tr.d_phi[i]
    flat_cond = np.repeat(train.condition, m)
    flat_chan = np.tile(np.arange(m), len(train.y))
    same = (flat_cond[:, None] == flat_cond[None]) & (flat_chan[:, None] == flat_chan[None])
    sd = train.model_sd.ravel()
    cov = np.diag((tr_noise ** 2).ravel()) + same * np.outer(sd, sd)
    P = np.diag(np.concatenate([np.full(U * K, 1 / S_THETA ** 2), 1 / shared.prior ** 2]))
    post = np.linalg.inv(J.T @ np.linalg.solve(cov, J) + P)
    g = np.zeros((m, U * K + p))
    for i in range(n):
        u = test.unit[i]
        g[:, u * K:(u + 1) * K] += ev.d_theta[i] / n
        g[:, U * K:] += ev.d_phi[i] / n
    var = np.einsum("mi,ij,mj->m", g, post, g) + np.sum(noise[held] ** 2, axis=0) / n ** 2 \
        + test.model_sd.mean(axis=0) ** 2
    np.testing.assert_allclose(std, np.sqrt(var), rtol=1e-6)


def test_adapt_with_the_model_error_shared_records_it_and_the_fitted_offsets():
    """``hyprog adapt --model-error-shared`` through the library: the record says so and
    carries each condition's fitted offset per channel, in % of the reading; ``assess``
    refits the record the same way."""
    from calibration.adaptation import adapt
    from calibration.adaptation.adapt import assess
    from calibration.adaptation.groups import build_groups

    channels = ("T24", "T30", "T50")
    groups = build_groups(channels, ["design_scaling"])
    rng = np.random.default_rng(3)
    model = LinearModel((1, 2, 3), len(channels), sum(len(c.params) for c in groups), rng)
    model.candidates = groups
    for c in model.a:  # readings of a sensible size, so that % of them mean something
        model.a[c] = model.a[c] + 500.0
    rows = []
    for u in range(1, 7):
        for cyc in range(1, 10):
            cond = 1 + cyc % 3
            w = np.array([[cond, 0.0, 0.0, 0.0]])
            y = model.evaluate(w, np.zeros((1, K)), channels, np.zeros(model.n_phi)).y[0]
            y = y + 0.5 * cond + rng.normal(scale=0.1, size=len(channels))
            rows.append({"unit": u, "cycle": cyc, "condition": cond,
                         **dict(zip(W_NAMES, w[0], strict=True)),
                         **dict(zip(channels, y, strict=True))})
    df = pd.DataFrame(rows)
    res = adapt(df, channels, ("design_scaling",), model=model, model_error=0.002,
                model_error_shared=True)
    rec = res.record()
    assert rec["data"]["model_error_shared"] is True
    offsets = rec["selection"]["discrepancy_pct"]["after"]
    assert sorted(offsets) == [1, 2, 3] and set(offsets[1]) == set(channels)
    assert all(np.isfinite(v) for row in offsets.values() for v in row.values())
    fit, _ = assess(df, rec, model=model)
    assert fit.discrepancy is not None
    np.testing.assert_allclose(fit.phi, res.selection.fit.phi, atol=1e-6)
    independent = adapt(df, channels, ("design_scaling",), model=model, model_error=0.002,
                        model_error_shared=False)
    assert independent.record()["selection"]["discrepancy_pct"]["after"] is None
    assert independent.record()["data"]["model_error_shared"] is False
    # shared is the default whenever there is a model error; with none there is nothing
    # to share, and only asking for it explicitly is refused
    assert fleet_data(df, channels, model_error=0.002)[0].shared_error
    assert not fleet_data(df, channels, model_error=0.0)[0].shared_error


def test_held_out_engines_keep_the_offsets_the_other_engines_gave():
    """The model's error at a condition is every engine's: a held-out engine's health is
    fitted under the other engines' offsets (``hold_discrepancy``), which is least squares
    on the readings less the offsets with the noise alone; ``engines_out`` runs so."""
    from calibration.adaptation.selection import engines_out

    model, data, shared, noise = fleet(True)
    out = data.unit >= 4
    train, test = data.subset(~out), data.subset(out)
    fit = fit_fleet(model, train, shared, max_iter=100)
    own = fit_fleet(model, test, Shared.none(), fit.phi, discrepancy0=fit.offsets,
                    hold_discrepancy=True, max_iter=100)
    np.testing.assert_array_equal(own.discrepancy, fit.discrepancy)
    m = test.y.shape[1]
    shifted = test.y - fit.discrepancy[np.searchsorted(fit.discrepancy_conditions,
                                                       test.condition)]
    ev = model.evaluate(test.w, np.zeros((len(test.y), K)), None, fit.phi)
    for u in range(test.n_units):
        rows = test.unit == u
        A = ev.d_theta[rows].reshape(-1, K)
        w = 1.0 / noise[out][rows].ravel() ** 2
        r = (shifted[rows] - ev.y[rows]).ravel()
        H = A.T @ (w[:, None] * A) + np.eye(K) / S_THETA ** 2
        np.testing.assert_allclose(own.delta[u], np.linalg.solve(H, A.T @ (w * r)),
                                   rtol=1e-5, atol=1e-9)
    assert own.border_cov.shape == (0, 0) and m == own.discrepancy.shape[1]
    assert np.isfinite(engines_out(model, data, shared, fit_fleet(model, data, shared)))


def test_a_prediction_std_at_a_condition_whose_offsets_were_fitted_is_refused():
    from calibration.adaptation.fleet_fit import evaluate, mean_prediction_std

    model, data, shared, _ = fleet(True)
    fit = fit_fleet(model, data, shared)
    ev, _, ok = evaluate(model, data, fit.delta, fit.phi, derivatives=True)
    with pytest.raises(ValueError, match="condition the fit did not see"):
        mean_prediction_std(fit, ev, data, np.arange(data.n_units), ok)
    with pytest.raises(ValueError, match="needs the model error"):
        fit_fleet(model, FleetData(**{**vars(data), "model_sd": None}), shared)
