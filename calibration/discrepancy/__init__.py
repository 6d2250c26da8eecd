"""The model-discrepancy loop: find what a calibrated model lacks, add it, prove the fix.

A calibrated model that still disagrees with the data is telling you something. This package
finds out what (``hyprog discover``), one job per module:

==================  =========================================================================
module              job
==================  =========================================================================
candidates          the candidate effects (library effects, sensor effects on every channel)
                    and their exact output sensitivities through one model variant
null_fit            the fit tested against: theta per flight cycle as a slow random walk
                    (+ accepted effects), warm-started by an existing estimator, polished by
                    bounded Gauss-Newton with exact Jacobians
noise_check         the noise model per channel (successive differences), before thresholds
drift_mle           the random-walk rate q by maximum marginal likelihood (no hand-set drift)
score_statistics    efficient score statistics of every candidate at once, chi-bar-squared
max_stat            the family-wise critical value by sampling the scores' null N(0, C)
confirm             joint bounded refit, likelihood ratio, held-out whole flights
identifiability     projected signature, "absorbed by theta", "ambiguous: A or B", minimum
                    detectable size
unknown             structure no candidate explains and the hint (sparse regression)
loop                the iteration and the verdict
normal_matrix       the bordered block-diagonal Gauss-Newton matrix over units and its solves
synthetic           a simulated unit with an effect switched on (tests and benchmarks)
discovery_report    Markdown + JSON + PNG, before and after
==================  =========================================================================

Design decisions (what was chosen and why)
------------------------------------------
1. **Null fit with slowly drifting theta.** theta is constant within a flight and a random walk
   between flights (``q`` per sqrt(hour)), the exact prior of N-CMAPSS and the simulator. A
   filter with loose process noise would absorb any effect whose signature lies in the span of
   ``dF/dtheta``; a per-cycle theta cannot absorb what varies with the operating point within a
   flight. The starting point is the same fit on every 16th sample of each flight
   (``coarse``, the default: a sixteenth of the cost per iteration, and the full fit then
   needs one step) or an estimator of :mod:`calibration` through its public API (``mhe``,
   ``ukf``, ``ekf``, ``map_cycle``); a bounded Gauss-Newton polish reaches the MAP of the
   per-cycle model, so that the gradient and information the tests need are those of one
   well-defined likelihood. A fit that starts where another ended (the drift refit, the
   held-out and training fits) reuses its linearisation (:meth:`.null_fit.Problem.masked`)
   instead of evaluating the model again: the model's sensitivities are the cost. ``q`` is
   estimated by maximum marginal likelihood (exact for the linearised model) unless given.
2. **Noise first.** Every threshold assumes the documented ``R``. The noise level per channel
   is estimated from successive differences within flights (von Neumann 1941), which a smooth
   model error does not inflate; channels off by more than 10 % (and significantly) are
   rescaled and reported.
3. **Score tests (Rao 1948).** Every candidate is tested from the null fit alone: the exact
   gradient ``g`` and Gauss-Newton information ``H`` in (theta, phi) from the model's
   sensitivities, the efficient score ``g_j - H_jN H_NN^-1 g_N`` and information
   ``S_j = H_jj - H_jN H_NN^-1 H_Nj`` (what theta cannot already explain). Cost: one
   linearisation for all candidates, no re-solve per candidate. Parameters whose neutral value
   is the end of their physical range (a bleed, an off-take, a loss) are one-sided: their null
   is on the boundary and the statistic is chi-bar-squared (Silvapulle & Sen 2005, ch. 3;
   Self & Liang 1987), weights estimated from the same Gaussian draws. A parameter that is
   only identified when the effect is present (the Reynolds effect's flow ratio, Davies 1977)
   is held at its documented value.
4. **Family-wise control.** The scores of all candidates are jointly Gaussian with the known
   covariance ``S_TT``; the alpha quantile of the smallest p-value over draws of ``N(0, S_TT)``
   is the single-step min-P critical value of Westfall & Young (1993), the max-T method for
   correlated tests of Hothorn, Bretz & Westfall (2008). No model run is needed and the
   correlation between candidates (a T48 bias and a bleed both move T48) is exact. Effect
   parameters are fleet-wide (shared by every unit), so the scores pool over units by
   construction.
5. **Confirmation.** The best candidate is refitted jointly with theta (warm-started, bounded
   Gauss-Newton with exact Jacobians: the same optimiser as the null fit; the brief asked for
   IPOPT through CasADi, but the refit has only (theta per cycle, phi) as variables once the
   steady state is solved implicitly, and ``scipy.optimize.lsq_linear`` solves each bounded
   step exactly, so IPOPT over every sample's unknowns would add cost and nothing else). It
   must give a significant likelihood ratio (same chi-bar-squared null, family-wise critical
   value), explain at least 40 % of the residual's chi-square excess (a wrong candidate
   that only takes a corner of a large undeclared effect is not added), and lower the residual
   on held-out whole flights (every third cycle, never seen by either fit). phi is reported
   with its standard error from the joint fit's information (theta uncertainty included).
6. **Can the data tell it apart?** The projected signature ``(I - P_theta) J_j`` (its squared
   norm is ``S_jj``): below 5 % of the whole signature the candidate is "absorbed by theta"
   (it would bias the health estimate; not detectable from residuals). Two significant
   candidates with projected signatures correlated above 0.95 whose refits' likelihoods differ
   by less than 5 log-units are "ambiguous: A or B", with the operating-point bins that
   separate them. The minimum detectable size at the family-wise level with 80 % power follows
   from the noncentral chi-square of the score statistic.
7. **Iterate** with the accepted effects as nuisance parameters until no candidate is
   significant (or ``max_effects``).
8. **Unknown effect.** On the final residual, per channel: bias, dependence on a documented
   basis of operating variables (F-test), whiteness (lag-1 autocorrelation), Bonferroni over
   channels and tests; channels with structure get a hint from a forward-stepwise sparse
   regression with a BIC stop (:mod:`.unknown` documents the basis).
9. **Before and after** on held-out flights (residual RMSE and bias in noise units, lag-1
   autocorrelation, chi^2 per degree of freedom) and, on simulated data, theta_hat against the
   truth.

Map adaptation: the effect ``map_scaling`` (:mod:`engine_model.physics.effect_library`: efficiency
and flow scalers of one component, linear and quadratic in its corrected speed minus one) is a
candidate when named (``--candidates ...,map_scaling``), one instance per component, so that
a model whose map shape is off at part power is corrected and the component named. It is not
a default candidate, because four free coefficients per component are flexible enough to act
as a proxy for other effects: with it, an undeclared customer bleed withheld from the
candidates became ``map_scaling_HPT`` plus a nozzle area ("partly explained") instead of an
unknown effect. Without it, the reverse: an HPC efficiency error of 1 % at 80 % corrected
speed was taken for an HP off-take of 72 kW ("partly explained"). So: run the default list
first; when it leaves structure or adds an effect that explains only part of the residual,
run again with ``map_scaling`` (README).

Not done: series effects (spool and thermal dynamics) have no steady parameter and are left to
the unknown-effect tests (the basis holds the rates of the operating variables).
"""

from engine_model.lazy_names import lazy_names

# name -> submodule that defines it, imported when the name is first asked for (PEP 562,
# :mod:`engine_model.lazy_names`): the loop imports scipy.stats and the identifiability
# machinery (0.7 s), which importing another module of the package (``drift_mle`` for
# ``calibrate --drift mle``, ``candidates``) does not need
_LAZY = {"VERDICTS": "loop", "DiscoverOptions": "loop", "Discovery": "loop",
         "discover": "loop"}

__all__ = ["VERDICTS", "DiscoverOptions", "Discovery", "discover"]

__getattr__, __dir__ = lazy_names(__name__, _LAZY)
