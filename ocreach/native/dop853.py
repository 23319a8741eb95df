"""The Dormand-Prince 8(5,3) step as a CasADi Function and the C driver loop around it.

Hairer, Norsett & Wanner, *Solving ODEs I*, Sec. II.10, with SciPy's ``DOP853`` tableau, error
norm, step-size controller and initial-step rule.  One step (12 stages, FSAL derivative, error
norm) is one CasADi Function built from the right-hand side (:func:`build_step`); the driver
(:data:`DRIVER_SRC`) is included after CasADi's generated code and loops over samples and steps
in C with one step size per sample.
"""
from __future__ import annotations

import casadi as ca
from scipy.integrate._ivp import dop853_coefficients as _dop

__all__ = ["DRIVER_SRC", "ERR_EXP", "MAX_FACTOR", "MIN_FACTOR", "SAFETY", "build_step", "dense_rhs"]

# --------------------------------------------------------------------------- DOP853 constants
_NS = _dop.N_STAGES  # 12
_A = _dop.A[:_NS, :_NS]
_B = _dop.B
_C = _dop.C[:_NS]
_E3 = _dop.E3
_E5 = _dop.E5
ERR_EXP = -1.0 / 8.0  # -1 / (error estimator order + 1), as SciPy's DOP853
SAFETY, MIN_FACTOR, MAX_FACTOR = 0.9, 0.2, 10.0


def dense_rhs(rhs: ca.Function) -> ca.Function:
    """``rhs`` with a dense output.  A structurally zero derivative (e.g. ``dlam_p/dt = 0`` of a
    double integrator) makes CasADi's generated C write only the non-zeros, which the native
    driver would read as a dense vector of length ``n_y``."""
    if rhs.sparsity_out(0).is_dense():
        return rhs
    y, t, a = (ca.MX.sym(rhs.name_in(i), rhs.sparsity_in(i)) for i in range(3))
    return ca.Function(rhs.name(), [y, t, a], [ca.densify(rhs(y, t, a))],
                       rhs.name_in(), rhs.name_out())


def build_step(rhs: ca.Function) -> ca.Function:
    """One DOP853 step ``(y, f0, t, h, a, rtol, atol) -> (y_new, f_new, err)``.

    ``err`` is SciPy's DOP853 error norm (Hairer's combined 5th/3rd order estimate);
    a step is accepted when ``err < 1``.  ``h = 0`` returns ``y`` with ``err = 0``.
    """
    n_y = rhs.size1_in(0)
    n_a = rhs.size1_in(2)
    y = ca.MX.sym("y", n_y)
    f0 = ca.MX.sym("f0", n_y)
    t = ca.MX.sym("t")
    h = ca.MX.sym("h")
    a = ca.MX.sym("a", n_a)
    rtol = ca.MX.sym("rtol", n_y)
    atol = ca.MX.sym("atol", n_y)
    K = [f0]
    for s in range(1, _NS):
        dy = sum(float(_A[s, j]) * K[j] for j in range(s) if _A[s, j] != 0.0)
        K.append(rhs(y + h * dy, t + float(_C[s]) * h, a))
    y_new = y + h * sum(float(_B[j]) * K[j] for j in range(_NS))
    f_new = rhs(y_new, t + h, a)
    K.append(f_new)
    scale = atol + ca.fmax(ca.fabs(y), ca.fabs(y_new)) * rtol
    e5 = sum(float(_E5[j]) * K[j] for j in range(_NS + 1) if _E5[j] != 0.0) / scale
    e3 = sum(float(_E3[j]) * K[j] for j in range(_NS + 1) if _E3[j] != 0.0) / scale
    n5 = ca.sumsqr(e5)
    n3 = ca.sumsqr(e3)
    denom = ca.fmax(n5 + 0.01 * n3, 1e-300)
    err = ca.fabs(h) * n5 / ca.sqrt(denom * n_y)
    y_new, f_new = ca.densify(y_new), ca.densify(f_new)
    return ca.Function(f"dop853_{rhs.name()}", [y, f0, t, h, a, rtol, atol], [y_new, f_new, err],
                       ["y", "f0", "t", "h", "a", "rtol", "atol"], ["y_new", "f_new", "err"])


_DRIVER_COMMON = r'''
#include <math.h>
#include <stdlib.h>
#include <string.h>

#define OCR_CAT2(a, b) a##b
#define OCR_CAT(a, b) OCR_CAT2(a, b)

static int ocr_all_finite(const double* v, long n) {
  for (long i = 0; i < n; ++i) if (!isfinite(v[i])) return 0;
  return 1;
}

static double ocr_rms(const double* v, const double* scale, long n) {
  double s = 0.0;
  for (long i = 0; i < n; ++i) { double q = v[i] / scale[i]; s += q * q; }
  return sqrt(s / (double)n);
}

/* Step-size underflow test of the drivers: h_abs < 10 * |nextafter(t, dir * inf) - t|.  The
 * spacing of doubles at t is at most 2^-52 |t| (or 4.9e-324 near 0), so nextafter is only
 * called when h_abs is that small (it was ~2% of an integration). */
static inline int ocr_too_small(double h_abs, double t, double dir) {
  if (h_abs >= 2.3e-15 * fabs(t) && h_abs >= 1e-322) return 0;
  return h_abs < 10 * fabs(nextafter(t, dir * INFINITY) - t);
}

/* err^(-1/8) of the step-size controller as three square roots (SciPy: err ** (-1/8)); the
 * same to a few ulps and ~4x cheaper than pow, which was ~15% of a 4-state integration. */
static inline double ocr_err_factor(double err) { return 1.0 / sqrt(sqrt(sqrt(err))); }

/* Start of one sample: f = RHS(t, y) and the first step size *h_abs (the caller's guess
 * h_guess > 0, else Hairer, Norsett & Wanner II.4 as SciPy's select_initial_step).  tmp holds
 * 3 ny doubles.  Returns 0, or 3 if f is not finite. */
static int ocr_start(long ny, const double* y, double t, double t1, const double* a,
                     const double* rtol, const double* atol, double h_guess, double* f,
                     double* tmp, const casadi_real** arg, casadi_real** res, casadi_int* iw,
                     casadi_real* w, double* h_abs) {
  double dir = (t1 >= t) ? 1.0 : -1.0, span = fabs(t1 - t);
  double *sc = tmp, *y1 = tmp + ny, *f1 = tmp + 2 * ny;
  arg[0] = y; arg[1] = &t; arg[2] = a; res[0] = f;
  RHS(arg, res, iw, w, 0);
  if (!ocr_all_finite(f, ny)) return 3;
  if (h_guess > 0.0) { *h_abs = h_guess < span ? h_guess : span; return 0; }
  for (long i = 0; i < ny; ++i) sc[i] = atol[i] + fabs(y[i]) * rtol[i];
  double d0 = ocr_rms(y, sc, ny), d1 = ocr_rms(f, sc, ny);
  double h0 = (d0 < 1e-5 || d1 < 1e-5) ? 1e-6 : 0.01 * d0 / d1;
  if (h0 > span) h0 = span;
  double th = t + dir * h0;
  for (long i = 0; i < ny; ++i) y1[i] = y[i] + dir * h0 * f[i];
  arg[0] = y1; arg[1] = &th; arg[2] = a; res[0] = f1;
  RHS(arg, res, iw, w, 0);
  for (long i = 0; i < ny; ++i) y1[i] = f1[i] - f[i];
  double d2 = ocr_rms(y1, sc, ny) / h0, dm = d1 > d2 ? d1 : d2, h1;
  if (dm <= 1e-15) h1 = (1e-6 > h0 * 1e-3) ? 1e-6 : h0 * 1e-3;
  else h1 = pow(0.01 / dm, 1.0 / 8.0);
  *h_abs = (100 * h0 < h1) ? 100 * h0 : h1;
  if (!isfinite(*h_abs)) *h_abs = 1e-6;
  return 0;
}
'''


DRIVER_SRC = _DRIVER_COMMON + r'''/* Adaptive Dormand-Prince 8(5,3) driver for ocreach.native.integrator.integrate_batch.
 *
 * Included after the CasADi-generated code of STEP (one DOP853 step with error norm, see
 * ocreach.native.dop853.build_step) and RHS.  Loops over samples and steps in C; the step-size
 * controller matches SciPy's DOP853 (safety 0.9, factors in [0.2, 10], exponent -1/8) and the
 * initial step follows Hairer's algorithm as SciPy's select_initial_step.
 * Status per sample: 0 ok, 1 max_steps exceeded, 2 step-size underflow, 3 non-finite value.
 * Threads of one batch take samples from the shared counter *queue (NULL: this call's own).
 * H[s] > 0 on entry is the first step size to try (instead of Hairer's rule); on a sample's
 * last step H[s] gets the step size the controller proposed before clipping it to t1.
 */
CASADI_SYMBOL_EXPORT int ocreach_integrate(long N, long ny, long na, double* Y, const double* T0,
                                           const double* T1, const double* A, const double* rtol,
                                           const double* atol, long max_steps, int* status,
                                           double* t_reached, long* n_steps, double* H,
                                           long* queue) {
  casadi_int sa, sr, si, sw, sa2, sr2, si2, sw2;
  OCR_CAT(STEP, _work)(&sa, &sr, &si, &sw);
  OCR_CAT(RHS, _work)(&sa2, &sr2, &si2, &sw2);
  if (sa2 > sa) sa = sa2; if (sr2 > sr) sr = sr2; if (si2 > si) si = si2; if (sw2 > sw) sw = sw2;
  const casadi_real** arg = (const casadi_real**)malloc(sizeof(casadi_real*) * (sa + 8));
  casadi_real** res = (casadi_real**)malloc(sizeof(casadi_real*) * (sr + 8));
  casadi_int* iw = (casadi_int*)malloc(sizeof(casadi_int) * (si + 1));
  casadi_real* w = (casadi_real*)malloc(sizeof(casadi_real) * (sw + 1));
  double* buf = (double*)malloc(sizeof(double) * 6 * ny);
  if (!arg || !res || !iw || !w || !buf) return -1;
  double *f = buf, *yn = buf + ny, *fn = buf + 2 * ny, *sc = buf + 3 * ny;  /* sc: 3 ny */
  int n_fail = 0;
  long next = 0;
  if (!queue) queue = &next;
  for (;;) {  /* samples from the counter shared with the other threads of this batch */
    long s = __atomic_fetch_add(queue, 1, __ATOMIC_RELAXED);
    if (s >= N) break;
    double* y = Y + s * ny;
    const double* a = A + s * na;
    double t = T0[s], t1 = T1[s], err, h_abs;
    double dir = (t1 >= t) ? 1.0 : -1.0;
    long steps = 0;
    int rejected = 0;
    status[s] = 0;
    n_steps[s] = 0;
    t_reached[s] = t;
    if (t == t1) continue;
    if ((status[s] = ocr_start(ny, y, t, t1, a, rtol, atol, H[s], f, sc, arg, res, iw, w, &h_abs))) {
      ++n_fail;
      continue;
    }
    for (;;) {
      if (++steps > max_steps) { status[s] = 1; break; }
      if (ocr_too_small(h_abs, t, dir)) { status[s] = 2; break; }
      double t_new = t + dir * h_abs;
      int last = dir * (t_new - t1) >= 0;
      if (last) { t_new = t1; H[s] = h_abs; }
      double h = t_new - t;
      arg[0] = y; arg[1] = f; arg[2] = &t; arg[3] = &h; arg[4] = a; arg[5] = rtol; arg[6] = atol;
      res[0] = yn; res[1] = fn; res[2] = &err;
      STEP(arg, res, iw, w, 0);
      if (isfinite(err) && err < 1.0) {
        double fac = (err == 0.0) ? 10.0 : 0.9 * ocr_err_factor(err);
        if (fac > 10.0) fac = 10.0;
        if (rejected && fac > 1.0) fac = 1.0;
        h_abs = fabs(h) * fac;
        rejected = 0;
        if (!ocr_all_finite(yn, ny)) { status[s] = 3; break; }
        memcpy(y, yn, sizeof(double) * ny);
        memcpy(f, fn, sizeof(double) * ny);
        t = t_new;
        if (last) break;
      } else {
        double fac = isfinite(err) ? 0.9 * ocr_err_factor(err) : 0.2;
        if (fac < 0.2) fac = 0.2;
        h_abs *= fac;
        rejected = 1;
      }
    }
    t_reached[s] = t;
    n_steps[s] = steps;
    if (status[s]) ++n_fail;
  }
  free(arg); free(res); free(iw); free(w); free(buf);
  return n_fail;
}
'''


DRIVER_LANES_SRC = _DRIVER_COMMON + r'''/* The same adaptive DOP853 driver with OCR_W samples in SIMD lanes, over one or several
 * consecutive segments per sample.
 *
 * Included after the scalar CasADi code of RHS (Hairer's initial step of a sample without a step
 * size) and the lane code (ocreach.native.lanes) of the step Function LSTEP (inputs y, f0, t, h,
 * a, rtol, atol; outputs y_new, f_new, err) and of the right-hand side LRHS (inputs y, t, a;
 * output f), each component-major (n, OCR_W).  Every lane has its own sample, segment, time, step
 * size and accept/reject history; a lane whose sample is done takes the next one from the queue,
 * so the lanes stay busy until the batch runs dry (idle lanes step with h = 0).  A segment ends
 * exactly at its end time; the next one (new arguments, e.g. the next piecewise-constant control
 * of ocreach.dynamics.flow.propagate) starts from the step size the controller proposed before that last
 * step was clipped (H[s]), with rejected = 0 and a fresh derivative, exactly as a new call per
 * segment would.  The derivatives of all lanes that start a segment in one round are one LRHS
 * call, and the controller's err^(-1/8) is computed for all lanes at once; both are the same
 * operations per lane whatever the other lanes hold, so results do not depend on the lane (or
 * thread) a sample ran in.  Several threads may run one batch together: they take samples from
 * the shared counter *queue (atomically), so a thread that gets less CPU takes fewer samples.
 * max_steps counts per segment.  Status per sample as the scalar driver.
 */
typedef struct {
  long s, k;       /* sample index (-1: idle) and its current segment */
  long kc, ksub;   /* its control index k / m and k % m (no integer division per segment) */
  double t, t1, dir, h_abs, t_new;
  long steps, total;
  int rejected, last, pending;  /* pending: open segment k (or take a new sample) next round */
} ocr_lane;

/* Where segment k of sample s lives (strides in doubles). */
typedef struct {
  long K;                                /* segments per sample */
  const double *T0, *T1; long ts, tk;    /* times T0[s ts + k tk] -> T1[s ts + k tk] */
  const double* U; long us, uk, nu, m;   /* arguments 0..nu-1: U[s us + (k / m) uk + i] */
  const double* P; long ps, np;          /* arguments nu..nu+np-1: P[s ps + i] */
  const double* Y0;                      /* initial state Y0[s ny + i] */
  double* OUT; long os, ok;              /* state after segment k: OUT[s os + (k + 1) ok + i] */
  long* queue;     /* next sample to take, shared by the threads of one batch (NULL: this call's) */
} ocr_plan;

static int ocr_lanes_run(long N, long ny, const ocr_plan* pl, const double* rtol,
                         const double* atol, long max_steps, int* status, double* t_reached,
                         long* n_steps, double* H) {
  const long W = OCR_W, na = pl->nu + pl->np;
  casadi_int sa, sr, si, sw;
  OCR_CAT(RHS, _work)(&sa, &sr, &si, &sw);
  const casadi_real** arg = (const casadi_real**)malloc(sizeof(casadi_real*) * (sa + 8));
  casadi_real** res = (casadi_real**)malloc(sizeof(casadi_real*) * (sr + 8));
  casadi_int* iw = (casadi_int*)malloc(sizeof(casadi_int) * (si + 1));
  casadi_real* w = (casadi_real*)malloc(sizeof(casadi_real) * (sw + 1));
  long nbuf = W * (4 * ny + 2 * ny + na + ny + 5) + 5 * ny + na + 1;
  double* buf = (double*)calloc(nbuf, sizeof(double));
  ocr_lane* lane = (ocr_lane*)calloc(W, sizeof(ocr_lane));
  if (!arg || !res || !iw || !w || !buf || !lane) {
    free(arg); free(res); free(iw); free(w); free(buf); free(lane); return -1;
  }
  double *Ly = buf, *Lf = Ly + W * ny, *Lyn = Lf + W * ny, *Lfn = Lyn + W * ny;
  double *Lrt = Lfn + W * ny, *Lat = Lrt + W * ny, *La = Lat + W * ny, *Lt = La + W * na;
  double *Lh = Lt + W, *Lerr = Lh + W, *Lfac = Lerr + W, *Lbusy = Lfac + W;
  double *y = Lbusy + W, *f = y + ny, *sc = f + ny, *a = sc + 3 * ny;  /* sc: 3 ny */
  const long nu = pl->nu, np = pl->np, m = pl->m;
  for (long i = 0; i < ny; ++i)
    for (long l = 0; l < W; ++l) { Lrt[i * W + l] = rtol[i]; Lat[i * W + l] = atol[i]; }
  const double* lin[7] = {Ly, Lf, Lt, Lh, La, Lrt, Lat};
  double* lout[3] = {Lyn, Lfn, Lerr};
  const double* rin[3] = {Ly, Lt, La};
  double* rout[1] = {Lfn};
  long next = 0, active = 0, *queue = pl->queue ? pl->queue : &next;
  int n_fail = 0;
  char need_f[OCR_W];
  for (long l = 0; l < W; ++l) { lane[l].s = -1; lane[l].pending = 1; }
/* the state of lane l after segment k of its sample (also the state a failed sample stopped at) */
#define OCR_PUT(l, L) do { double* o_ = pl->OUT + (L)->s * pl->os + ((L)->k + 1) * pl->ok; \
    for (long i_ = 0; i_ < ny; ++i_) o_[i_] = Ly[i_ * W + (l)]; } while (0)
#define OCR_END(L, st) do { long s_ = (L)->s; status[s_] = (st); n_fail += (st) != 0; \
    t_reached[s_] = (L)->t; n_steps[s_] = (L)->total; (L)->s = -1; (L)->pending = 1; --active; } while (0)
#define OCR_NEXT(L) do { ++(L)->k; if (++(L)->ksub == m) { (L)->ksub = 0; ++(L)->kc; } } while (0)
  for (;;) {
    /* open the next segment of lanes that finished one; refill lanes whose sample is done */
    int n_need = 0;
    for (long l = 0; l < W; ++l) {
      ocr_lane* L = lane + l;
      need_f[l] = 0;
      while (L->pending) {
        if (L->s < 0) {
          long s = __atomic_fetch_add(queue, 1, __ATOMIC_RELAXED);
          if (s >= N) { L->pending = 0; break; }  /* queue empty: idle */
          L->s = s; L->k = 0; L->kc = 0; L->ksub = 0; L->total = 0; L->t = pl->T0[s * pl->ts];
          status[s] = 0;
          for (long i = 0; i < ny; ++i) Ly[i * W + l] = pl->Y0[s * ny + i];
          for (long i = 0; i < np; ++i) La[(nu + i) * W + l] = pl->P[s * pl->ps + i];
          ++active;
        }
        long s = L->s, k = L->k;
        if (k == pl->K) { OCR_END(L, 0); continue; }
        double t = pl->T0[s * pl->ts + k * pl->tk], t1 = pl->T1[s * pl->ts + k * pl->tk];
        L->t = t;
        if (t == t1) { OCR_PUT(l, L); OCR_NEXT(L); continue; }
        const double* u = pl->U + s * pl->us + L->kc * pl->uk;
        for (long i = 0; i < nu; ++i) La[i * W + l] = u[i];
        /* the next segment's control and output rows are read / written in a few steps: fetch
         * them now (cache misses on these rows were ~10% of the driver's time) */
        if (k + 1 < pl->K) {
          __builtin_prefetch(u + pl->uk);
          __builtin_prefetch(pl->OUT + s * pl->os + (k + 2) * pl->ok, 1);
        }
        double dir = (t1 >= t) ? 1.0 : -1.0, span = fabs(t1 - t), h_abs;
        if (H[s] > 0.0) {  /* step size given: the derivative comes from LRHS below */
          h_abs = H[s] < span ? H[s] : span;
          need_f[l] = 1; ++n_need;
        } else {  /* Hairer's initial step (scalar, two RHS calls) */
          for (long i = 0; i < ny; ++i) y[i] = Ly[i * W + l];
          for (long i = 0; i < na; ++i) a[i] = La[i * W + l];
          if (ocr_start(ny, y, t, t1, a, rtol, atol, H[s], f, sc, arg, res, iw, w, &h_abs)) {
            OCR_PUT(l, L); OCR_END(L, 3); continue;
          }
          for (long i = 0; i < ny; ++i) Lf[i * W + l] = f[i];
        }
        L->t1 = t1; L->dir = dir; L->h_abs = h_abs; L->steps = 0; L->rejected = 0;
        L->pending = 0;
      }
    }
    if (n_need) {  /* derivatives at the start of the opened segments in one lane call */
      int failed = 0;
      for (long l = 0; l < W; ++l) Lt[l] = lane[l].s >= 0 ? lane[l].t : 0.0;
      LRHS(rin, rout);
      for (long l = 0; l < W; ++l) {
        if (!need_f[l]) continue;
        int ok = 1;
        for (long i = 0; i < ny; ++i) { Lf[i * W + l] = Lfn[i * W + l]; ok &= isfinite(Lfn[i * W + l]) ? 1 : 0; }
        if (!ok) { OCR_PUT(l, lane + l); OCR_END(lane + l, 3); failed = 1; }
      }
      if (failed) continue;  /* refill the lanes that failed first */
    }
    if (active == 0) break;
    /* step sizes of the busy lanes; a lane that fails here is finished and refilled next round */
    for (long l = 0; l < W; ++l) {
      ocr_lane* L = lane + l;
      Lh[l] = 0.0;
      Lbusy[l] = 0.0;
      if (L->s < 0) continue;
      int st = 0;
      if (++L->steps > max_steps) st = 1;
      else if (ocr_too_small(L->h_abs, L->t, L->dir)) st = 2;
      if (st) { L->total += L->steps; OCR_PUT(l, L); OCR_END(L, st); continue; }
      double t_new = L->t + L->dir * L->h_abs;
      L->last = L->dir * (t_new - L->t1) >= 0;
      if (L->last) { t_new = L->t1; H[L->s] = L->h_abs; }
      L->t_new = t_new;
      Lt[l] = L->t;
      Lh[l] = t_new - L->t;
      Lbusy[l] = 1.0;
    }
    LSTEP(lin, lout);
    /* all lanes at once: 0.9 err^(-1/8) (as ocr_err_factor), the accept test
     * (isfinite(err) && err < 1) and the finiteness of y_new; accepted lanes take y_new, f_new */
    ocr_v e = ocr_ld(Lerr);
    ocr_st(Lfac, ocr_bc(0.9) * (1.0 / OCR_MAP1(sqrt, OCR_MAP1(sqrt, OCR_MAP1(sqrt, e)))));
    ocr_m acc = (e < 1.0) & (e > -INFINITY) & (ocr_ld(Lbusy) != 0.0), fin = acc;
    for (long i = 0; i < ny; ++i) { ocr_v v = ocr_ld(Lyn + i * W); fin &= (v - v) == 0.0; }
    for (long i = 0; i < ny; ++i) {
      ocr_st(Ly + i * W, ocr_sel(fin, ocr_ld(Lyn + i * W), ocr_ld(Ly + i * W)));
      ocr_st(Lf + i * W, ocr_sel(fin, ocr_ld(Lfn + i * W), ocr_ld(Lf + i * W)));
    }
    for (long l = 0; l < W; ++l) {
      ocr_lane* L = lane + l;
      if (Lbusy[l] == 0.0) continue;
      double err = Lerr[l], h = Lh[l];
      if (acc[l]) {
        double fac = (err == 0.0) ? 10.0 : Lfac[l];
        if (fac > 10.0) fac = 10.0;
        if (L->rejected && fac > 1.0) fac = 1.0;
        L->h_abs = fabs(h) * fac;
        L->rejected = 0;
        if (!fin[l]) { L->total += L->steps; OCR_PUT(l, L); OCR_END(L, 3); continue; }
        L->t = L->t_new;
        if (L->last) { L->total += L->steps; OCR_PUT(l, L); OCR_NEXT(L); L->pending = 1; }
      } else {
        double fac = isfinite(err) ? Lfac[l] : 0.2;
        if (fac < 0.2) fac = 0.2;
        L->h_abs *= fac;
        L->rejected = 1;
      }
    }
  }
#undef OCR_PUT
#undef OCR_END
#undef OCR_NEXT
  free(arg); free(res); free(iw); free(w); free(buf); free(lane);
  return n_fail;
}

/* One segment per sample: T0[s] -> T1[s] with arguments A[s], Y advanced in place (the
 * signature of the scalar driver). */
CASADI_SYMBOL_EXPORT int ocreach_integrate(long N, long ny, long na, double* Y, const double* T0,
                                           const double* T1, const double* A, const double* rtol,
                                           const double* atol, long max_steps, int* status,
                                           double* t_reached, long* n_steps, double* H,
                                           long* queue) {
  ocr_plan pl = {1, T0, T1, 1, 0, A, na, 0, na, 1, A, 0, 0, Y, Y, ny, 0, queue};
  return ocr_lanes_run(N, ny, &pl, rtol, atol, max_steps, status, t_reached, n_steps, H);
}

/* K segments per sample on a shared grid G[0..K]: segment k under U[s, k / m] (U: N x K/m x nu)
 * and P[s] (N x np), from Y0 (N x ny); OUT (N x (K+1) x ny) gets the state after every segment
 * (OUT[s, 0] is left to the caller). */
CASADI_SYMBOL_EXPORT int ocreach_propagate(long N, long ny, long K, const double* G,
                                           const double* U, long nu, long m, const double* P,
                                           long np, const double* Y0, double* OUT,
                                           const double* rtol, const double* atol, long max_steps,
                                           int* status, double* t_reached, long* n_steps,
                                           double* H, long* queue) {
  ocr_plan pl = {K, G, G + 1, 0, 1, U, (K / m) * nu, nu, nu, m, P, np, np, Y0, OUT,
                 (K + 1) * ny, ny, queue};
  return ocr_lanes_run(N, ny, &pl, rtol, atol, max_steps, status, t_reached, n_steps, H);
}
'''
