/* A hand-vectorised C loop of the benchmark square (sim/bench.py square_system), for the benchmark only.
 *
 * The same physics as golden and the cpu backend (MODEL.md v2: the exact damper solve, the stops, gravity,
 * pinned nodes) specialised to what a C programmer would write for this mesh: 2D, one material (scalar
 * parameters), structure of arrays, restrict pointers, GCC's vectoriser (-O3 -march=native, omp simd, the
 * vector exp of glibc's libmvec) on the element pass and on the Newton solve of the damper, which runs over
 * the compacted list of the elements whose drive is on the exponential piece. Built and loaded by
 * bench/square.py; its result is checked against the cpu backend before it is timed.
 */
#include <math.h>
#include <stdint.h>

typedef struct {
    double k1, c1, a_min, a_max, c_min, c_max, B, f1, f2, Y1, Y2, g0, g1, dt;
} Material;

static inline double H(const Material *m, double t) { return t * exp(m->B * (t - m->f1)) / m->c_max; }

/* golden/elements.py solve_convex for F(t) = with_t t + c H(t) on [f1, f2], one element (the stops) */
static double solve1(const Material *m, double y, double with_t, double c) {
    double lo = m->f1, hi = m->f2;
    double Flo = with_t * lo + c * H(m, lo), Fhi = with_t * hi + c * H(m, hi);
    double width = Fhi > Flo ? Fhi - Flo : 1.0;
    double t = fmin(fmax(lo + (y - Flo) * (hi - lo) / width, lo), hi);
    for (int it = 0; it < 100; it++) {
        double ex = exp(m->B * (t - m->f1));
        double r = (with_t * t + c * (t * ex / m->c_max)) - y;
        if (!(fabs(r) > 1e-12 * fabs(y) + 1e-300)) return t;
        t = fmin(fmax(t - r / (with_t + c * (ex * (1.0 + m->B * t) / m->c_max)), lo), hi);
    }
    return NAN;
}

int run(int64_t n_steps, int64_t N, int64_t E, const uint32_t *restrict ei, const uint32_t *restrict ej,
        double *restrict x0, double *restrict x1, double *restrict v0, double *restrict v1,
        double *restrict a, const double *restrict L, const double *restrict inv_m_dt,
        const double *restrict free_, const Material *m,
        /* scratch: */ double *restrict d0, double *restrict d1, double *restrict Tl, double *restrict adot,
        double *restrict ldot_, double *restrict l_, double *restrict Y_, int32_t *restrict list,
        double *restrict t_, double *restrict F0, double *restrict F1)
{
    const double k1 = m->k1, c1 = m->c1, cmin = m->c_min, cmax = m->c_max, Y1 = m->Y1, Y2 = m->Y2;
    const double B = m->B, f1 = m->f1, f2 = m->f2, amin = m->a_min, amax = m->a_max, dt = m->dt;
    for (int64_t s = 0; s < n_steps; s++) {
        #pragma omp simd
        for (int64_t e = 0; e < E; e++) {             /* edges and Phi's linear pieces */
            uint32_t i = ei[e], j = ej[e];
            double dx = x0[j] - x0[i], dy = x1[j] - x1[i];
            double l = sqrt(dx * dx + dy * dy), inv_l = 1.0 / l;
            double ldot = (dx * (v0[j] - v0[i]) + dy * (v1[j] - v1[i])) * inv_l;
            double ae = a[e];
            double Y = k1 * (ae * l - L[e]) + c1 * ldot;
            double mag = fabs(Y);
            double c2 = mag < Y1 ? cmax : cmin;
            d0[e] = dx; d1[e] = dy; l_[e] = l; ldot_[e] = ldot; Y_[e] = Y;
            Tl[e] = Y * (c2 / (c1 + c2)) * inv_l;
            adot[e] = ((1.0 - ae) * ldot - Y / (c1 + c2)) * inv_l;
        }
        int64_t n = 0;                                 /* the exponential piece, not on a stop */
        for (int64_t e = 0; e < E; e++) {
            double mag = fabs(Y_[e]);
            if (Y1 <= mag && mag < Y2 && a[e] > amin && a[e] < amax) list[n++] = (int32_t)e;
        }
        /* Newton from the chord (golden's solve_convex), vectorised over the list; F(lo), F(hi) constant */
        const double Flo = f1 + c1 * H(m, f1), Fhi = f2 + c1 * H(m, f2);
        #pragma omp simd
        for (int64_t q = 0; q < n; q++) {
            double y = fabs(Y_[list[q]]);
            t_[q] = fmin(fmax(f1 + (y - Flo) * (f2 - f1) / (Fhi - Flo), f1), f2);
        }
        for (int it = 0; it < 100; it++) {
            int open = 0;
            #pragma omp simd reduction(|:open)
            for (int64_t q = 0; q < n; q++) {
                double y = fabs(Y_[list[q]]), t = t_[q];
                double ex = exp(B * (t - f1));
                double r = (t + c1 * (t * ex / cmax)) - y;
                int go = fabs(r) > 1e-12 * y + 1e-300;
                double tn = fmin(fmax(t - r / (1.0 + c1 * (ex * (1.0 + B * t) / cmax)), f1), f2);
                t_[q] = go ? tn : t;
                open |= go;
            }
            if (!open) break;
        }
        for (int64_t q = 0; q < n; q++) {
            int64_t e = list[q];
            double Y = Y_[e], t = t_[q], sgn = Y > 0 ? 1.0 : -1.0;
            double inv_l = 1.0 / l_[e];
            Tl[e] = sgn * t * inv_l;
            adot[e] = ((1.0 - a[e]) * ldot_[e] - sgn * H(m, t)) * inv_l;
        }
        for (int64_t e = 0; e < E; e++) {              /* the stops (scalar: rare) */
            double ae = a[e];
            if (ae > amin && ae < amax) continue;
            double l = l_[e], inv_l = 1.0 / l, ldot = ldot_[e], Y = Y_[e], mag = fabs(Y);
            double k1s = k1 * (ae * l - L[e]), T, wd;
            if (Y1 <= mag && mag < Y2) {
                double t = solve1(m, mag, 1.0, c1), sgn = Y > 0 ? 1.0 : -1.0;
                T = sgn * t; wd = sgn * H(m, t);
            } else {
                double c2 = mag < Y1 ? cmax : cmin;
                T = Y * (c2 / (c1 + c2)); wd = Y / (c1 + c2);
            }
            double W = (1.0 - ae) * ldot, ad = (W - wd) * inv_l;
            int lo = ae <= amin, hi = ae >= amax;
            if (hi && (ad > 0 || lo)) { T = k1s + c1 * ae * ldot; ad = 0.0; }
            else if (lo && ad < 0 && !hi) {
                double Wm = fabs(W), sgn = W > 0 ? 1.0 : -1.0;
                if (f1 / cmax <= Wm && Wm < f2 / cmin) T = sgn * solve1(m, Wm, 0.0, 1.0);
                else T = W * (Wm < f1 / cmax ? cmax : cmin);
                ad = 0.0;
            }
            Tl[e] = T * inv_l; adot[e] = ad;
        }
        for (int64_t p = 0; p < N; p++) { F0[p] = 0.0; F1[p] = 0.0; }
        for (int64_t e = 0; e < E; e++) {              /* scatter */
            double f0 = Tl[e] * d0[e], f1_ = Tl[e] * d1[e];
            F0[ei[e]] += f0; F1[ei[e]] += f1_;
            F0[ej[e]] -= f0; F1[ej[e]] -= f1_;
        }
        #pragma omp simd
        for (int64_t p = 0; p < N; p++) {
            double u0 = (v0[p] + F0[p] * inv_m_dt[p] + m->g0) * free_[p];
            double u1 = (v1[p] + F1[p] * inv_m_dt[p] + m->g1) * free_[p];
            v0[p] = u0; v1[p] = u1;
            x0[p] += u0 * dt; x1[p] += u1 * dt;
        }
        #pragma omp simd
        for (int64_t e = 0; e < E; e++) a[e] = fmin(fmax(a[e] + adot[e] * dt, amin), amax);
    }
    return 0;
}
