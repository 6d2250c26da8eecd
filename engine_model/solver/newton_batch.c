/* Batched damped Newton-chord solver for the engine's steady state, in C.
 *
 * Compiled together with the CasADi-generated residual and Jacobian (see codegen.py and
 * model.py), so a whole batch of operating points is solved without returning to Python
 * between iterations; points are spread over threads with OpenMP (each thread has its own
 * CasADi work arrays; the generated functions are pure).
 *
 * Per point, the iteration is the one documented in EngineModel._newton_python:
 *   - a fresh exact Jacobian (LU with partial pivoting) on the first iteration, after a
 *     step that raised the residual, and whenever a chord step reduced max|r| by less than a
 *     factor 4; otherwise the last factorisation is reused (one residual per iteration);
 *   - the Newton step is scaled so that no unknown moves by more than its step limit;
 *   - a step that raised max|r| is halved along the previous direction (backtracking);
 *   - the point leaves the loop when max|r| < tol; after max_iter iterations it is reported
 *     as not converged with its last residual norm.
 *
 * RES_FN and RESJAC_FN name the generated functions (set with -D by the build):
 *   RES_FN(x, w, theta, p) -> r ;  RESJAC_FN(x, w, theta, p) -> (r, dense J, column-major)
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>
#ifdef _OPENMP
#include <omp.h>
#endif

#define CINT long long int
#define MAXN 16

#define CAT_(a, b) a##b
#define CAT(a, b) CAT_(a, b)

int RES_FN(const double **arg, double **res, CINT *iw, double *w, int mem);
int CAT(RES_FN, _work)(CINT *sz_arg, CINT *sz_res, CINT *sz_iw, CINT *sz_w);
int RESJAC_FN(const double **arg, double **res, CINT *iw, double *w, int mem);
int CAT(RESJAC_FN, _work)(CINT *sz_arg, CINT *sz_res, CINT *sz_iw, CINT *sz_w);

/* LU with partial pivoting of the column-major n x n matrix a (in place); 0 if singular */
static int lu_factor(int n, double *a, int *piv) {
    for (int k = 0; k < n; ++k) {
        int p = k;
        double big = fabs(a[k + k * n]);
        for (int i = k + 1; i < n; ++i) {
            double v = fabs(a[i + k * n]);
            if (v > big) { big = v; p = i; }
        }
        piv[k] = p;
        if (!(big > 0.0) || !isfinite(big)) return 0;
        if (p != k)
            for (int j = 0; j < n; ++j) {
                double t = a[k + j * n]; a[k + j * n] = a[p + j * n]; a[p + j * n] = t;
            }
        double inv = 1.0 / a[k + k * n];
        for (int i = k + 1; i < n; ++i) a[i + k * n] *= inv;
        for (int j = k + 1; j < n; ++j) {
            double akj = a[k + j * n];
            if (akj != 0.0)
                for (int i = k + 1; i < n; ++i) a[i + j * n] -= a[i + k * n] * akj;
        }
    }
    return 1;
}

static void lu_solve(int n, const double *a, const int *piv, double *b) {
    for (int k = 0; k < n; ++k) {  /* row interchanges, in order (as LAPACK getrs) */
        int p = piv[k];
        if (p != k) { double t = b[k]; b[k] = b[p]; b[p] = t; }
    }
    for (int k = 0; k < n; ++k)  /* unit lower triangle */
        for (int i = k + 1; i < n; ++i) b[i] -= a[i + k * n] * b[k];
    for (int k = n - 1; k >= 0; --k) {
        b[k] /= a[k + k * n];
        for (int i = 0; i < k; ++i) b[i] -= a[i + k * n] * b[k];
    }
}

static double max_abs(int n, const double *r) {
    double m = 0.0;
    for (int i = 0; i < n; ++i) {
        double v = fabs(r[i]);
        if (!isfinite(v)) return INFINITY;
        if (v > m) m = v;
    }
    return m;
}

/* Solve npts points. Row-major inputs: W (npts, nw), TH (npts, nth), P (npts, np),
 * X (npts, nx) in: starting guess, out: solution. Outputs RN (max|r|), IT (iterations),
 * CONV (1 converged). Returns 0, or -1 if nx is larger than MAXN. */
int hyprog_newton_batch_lu(int npts, int nx, int nw, int nth, int np, const double *W,
                           const double *TH, const double *P, double *X, double *RN, int *IT,
                           int *CONV, double tol, int max_iter, const double *step_limit,
                           int n_threads, double *LU, int *PIV, int *HAVE);

int hyprog_newton_batch(int npts, int nx, int nw, int nth, int np, const double *W,
                        const double *TH, const double *P, double *X, double *RN, int *IT,
                        int *CONV, double tol, int max_iter, const double *step_limit,
                        int n_threads) {
    return hyprog_newton_batch_lu(npts, nx, nw, nth, np, W, TH, P, X, RN, IT, CONV, tol,
                                  max_iter, step_limit, n_threads, NULL, NULL, NULL);
}

/* As hyprog_newton_batch, with each point's Jacobian LU factors carried between calls:
 * LU (npts, nx*nx), PIV (npts, nx), HAVE (npts). A point with HAVE = 1 starts the chord
 * iteration from the stored factors instead of a fresh Jacobian (they are refreshed by the
 * usual rule when convergence is slow); on return every point stores its last factors. */
int hyprog_newton_batch_lu(int npts, int nx, int nw, int nth, int np, const double *W,
                           const double *TH, const double *P, double *X, double *RN, int *IT,
                           int *CONV, double tol, int max_iter, const double *step_limit,
                           int n_threads, double *LU, int *PIV, int *HAVE) {
    if (nx > MAXN) return -1;
    CINT a1, r1, iw1, w1, a2, r2, iw2, w2;
    CAT(RES_FN, _work)(&a1, &r1, &iw1, &w1);
    CAT(RESJAC_FN, _work)(&a2, &r2, &iw2, &w2);
    CINT sz_arg = a1 > a2 ? a1 : a2, sz_res = r1 > r2 ? r1 : r2;
    CINT sz_iw = iw1 > iw2 ? iw1 : iw2, sz_w = w1 > w2 ? w1 : w2;
    if (n_threads < 1) n_threads = 1;
    int failed = 0;
#pragma omp parallel num_threads(n_threads)
    {
        const double **arg = malloc(sizeof(double *) * (size_t)(sz_arg + 4));
        double **res = malloc(sizeof(double *) * (size_t)(sz_res + 2));
        CINT *iw = malloc(sizeof(CINT) * (size_t)(sz_iw + 1));
        double *work = malloc(sizeof(double) * (size_t)(sz_w + 1));
        if (!arg || !res || !iw || !work) {
#pragma omp atomic write
            failed = 1;
        } else {
#pragma omp for schedule(dynamic, 32)
            for (int pt = 0; pt < npts; ++pt) {
                double *x = X + (size_t)pt * nx;
                double r[MAXN], J[MAXN * MAXN], dx[MAXN], x_old[MAXN], dx_old[MAXN];
                int piv[MAXN];
                int need_j = 1, have_lu = 0, conv = 0, iters = 0;
                double alpha = 1.0, rn_old = INFINITY, rn_final = INFINITY;
                arg[1] = W + (size_t)pt * nw;
                arg[2] = TH + (size_t)pt * nth;
                arg[3] = P + (size_t)pt * np;
                for (int i = 0; i < nx; ++i) { x_old[i] = x[i]; dx_old[i] = 0.0; }
                if (LU && HAVE[pt]) {
                    memcpy(J, LU + (size_t)pt * nx * nx, sizeof(double) * (size_t)(nx * nx));
                    memcpy(piv, PIV + (size_t)pt * nx, sizeof(int) * (size_t)nx);
                    need_j = 0;
                    have_lu = 1;
                }
                for (int it = 0; it <= max_iter; ++it) {
                    int fresh = need_j;
                    arg[0] = x;
                    res[0] = r;
                    if (need_j) {
                        res[1] = J;
                        RESJAC_FN(arg, res, iw, work, 0);
                        have_lu = lu_factor(nx, J, piv);
                    } else {
                        RES_FN(arg, res, iw, work, 0);
                    }
                    double rn = max_abs(nx, r);
                    iters = it;
                    if (rn < tol) { conv = 1; rn_final = rn; break; }
                    if (it == max_iter) { rn_final = rn; break; }
                    if (rn >= rn_old) {  /* worse: backtrack along the previous direction */
                        alpha *= 0.5;
                        for (int i = 0; i < nx; ++i) x[i] = x_old[i] + alpha * dx_old[i];
                        need_j = 1;
                        rn_final = rn_old;
                        continue;
                    }
                    int finite = have_lu;
                    if (have_lu) {
                        for (int i = 0; i < nx; ++i) dx[i] = -r[i];
                        lu_solve(nx, J, piv, dx);
                        for (int i = 0; i < nx; ++i)
                            if (!isfinite(dx[i])) finite = 0;
                    }
                    if (!finite)
                        for (int i = 0; i < nx; ++i) dx[i] = 0.0;
                    double step = 1.0;
                    for (int i = 0; i < nx; ++i) {
                        double a = fabs(dx[i]);
                        if (a > 0.0 && step_limit[i] / a < step) step = step_limit[i] / a;
                    }
                    int slow = (!fresh) && (rn > 0.25 * rn_old);
                    need_j = slow || !finite;
                    for (int i = 0; i < nx; ++i) {
                        x_old[i] = x[i];
                        dx_old[i] = dx[i];
                        x[i] += step * dx[i];
                    }
                    alpha = step;
                    rn_old = rn;
                }
                RN[pt] = rn_final;
                IT[pt] = iters;
                CONV[pt] = conv;
                if (LU) {
                    HAVE[pt] = have_lu && conv;
                    if (HAVE[pt]) {
                        memcpy(LU + (size_t)pt * nx * nx, J, sizeof(double) * (size_t)(nx * nx));
                        memcpy(PIV + (size_t)pt * nx, piv, sizeof(int) * (size_t)nx);
                    }
                }
            }
        }
        free(arg); free(res); free(iw); free(work);
    }
    return failed ? -2 : 0;
}
