"""C source of the adaptive DOP853 driver loop used by :mod:`ocreach.flow`.

Kept as a Python string so it ships with the package without package-data settings.
"""

DRIVER_SRC = r'''/* Adaptive Dormand-Prince 8(5,3) driver for ocreach.flow.integrate_batch.
 *
 * Included after the CasADi-generated code of STEP (one DOP853 step with error norm, see
 * ocreach.flow._build_step) and RHS.  Loops over samples and steps in C; the step-size
 * controller matches SciPy's DOP853 (safety 0.9, factors in [0.2, 10], exponent -1/8) and the
 * initial step follows Hairer's algorithm as SciPy's select_initial_step.
 * Status per sample: 0 ok, 1 max_steps exceeded, 2 step-size underflow, 3 non-finite value.
 */
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

CASADI_SYMBOL_EXPORT int ocreach_integrate(long N, long ny, long na, double* Y, const double* T0,
                                           const double* T1, const double* A, const double* rtol,
                                           const double* atol, long max_steps, int* status,
                                           double* t_reached, long* n_steps) {
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
  double *f = buf, *yn = buf + ny, *fn = buf + 2 * ny, *sc = buf + 3 * ny, *y1 = buf + 4 * ny,
         *f1 = buf + 5 * ny;
  int n_fail = 0;
  for (long s = 0; s < N; ++s) {
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
    /* f(t0, y0) */
    arg[0] = y; arg[1] = &t; arg[2] = a; res[0] = f;
    RHS(arg, res, iw, w, 0);
    if (!ocr_all_finite(f, ny)) { status[s] = 3; ++n_fail; continue; }
    /* initial step (Hairer, Norsett & Wanner II.4) */
    for (long i = 0; i < ny; ++i) sc[i] = atol[i] + fabs(y[i]) * rtol[i];
    double d0 = ocr_rms(y, sc, ny), d1 = ocr_rms(f, sc, ny), span = fabs(t1 - t);
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
    h_abs = (100 * h0 < h1) ? 100 * h0 : h1;
    if (!isfinite(h_abs)) h_abs = 1e-6;
    for (;;) {
      if (++steps > max_steps) { status[s] = 1; break; }
      double min_step = 10 * fabs(nextafter(t, dir * INFINITY) - t);
      if (h_abs < min_step) { status[s] = 2; break; }
      double t_new = t + dir * h_abs;
      int last = dir * (t_new - t1) >= 0;
      if (last) t_new = t1;
      double h = t_new - t;
      arg[0] = y; arg[1] = f; arg[2] = &t; arg[3] = &h; arg[4] = a; arg[5] = rtol; arg[6] = atol;
      res[0] = yn; res[1] = fn; res[2] = &err;
      STEP(arg, res, iw, w, 0);
      if (isfinite(err) && err < 1.0) {
        double fac = (err == 0.0) ? 10.0 : 0.9 * pow(err, -1.0 / 8.0);
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
        double fac = isfinite(err) ? 0.9 * pow(err, -1.0 / 8.0) : 0.2;
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
