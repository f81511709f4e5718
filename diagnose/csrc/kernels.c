/*
 * Compiled kernels of the stiction diagnostics (diagnose/kernels.py loads them with ctypes).
 *
 * Built by pip when the package is installed (setup.py: portable flags, no -march=native, no
 * fused multiply-add, no fast-math). The vectorised kernels are compiled three times from
 * kernels_lanes.h, for the x86-64 baseline (SSE2, 2 lanes), AVX2 (4 lanes) and AVX-512 (8 lanes),
 * and the widest one the CPU supports is chosen when the library loads; lanes perform the same IEEE
 * operations at every width, so every CPU returns the same numbers. Elsewhere (ARM) only the
 * baseline is built.
 *
 * The valve step (valve_step.h) is the only implementation of the stiction model: every kernel
 * here, the simulator's valves and the Python classes (via valve_step1) run it.
 *
 * Arrays are C-contiguous float64 (int64 for delays, one byte per bool); the Python side checks
 * shapes before calling. min/max follow Python's builtins: max(a, b) = b > a ? b : a.
 */
#if !defined(__GNUC__)
#error "the stiction kernels need GCC or clang (vector extensions)"
#endif

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define KERNELS_ABI 8

static inline double nmax(double a, double b) { return b > a ? b : a; }
static inline double nmin(double a, double b) { return b < a ? b : a; }
static inline double clip100(double v) { return nmin(nmax(v, 0.0), 100.0); }
/*
 * Scratch memory of the scoring kernel, one set per thread, kept between calls: a local search
 * calls it thousands of times, and fresh rows for a long record on every call cost page faults
 * comparable to the work itself. Freed when the thread ends.
 */
enum { SCRATCH_UBUF, SCRATCH_ROWS, SCRATCH_ORDER, SCRATCH_SLOTS };
struct scratch {
    void *p[SCRATCH_SLOTS];
    size_t size[SCRATCH_SLOTS];
};
static pthread_key_t scratch_key;
static pthread_once_t scratch_once = PTHREAD_ONCE_INIT;

static void scratch_free(void *v)
{
    struct scratch *s = (struct scratch *)v;
    for (int i = 0; i < SCRATCH_SLOTS; i++)
        free(s->p[i]);
    free(s);
}

static void scratch_init(void) { pthread_key_create(&scratch_key, scratch_free); }

/* at least `bytes` of 64-byte aligned memory for `slot` of this thread (contents undefined), or NULL */
static void *scratch(int slot, size_t bytes)
{
    pthread_once(&scratch_once, scratch_init);
    struct scratch *s = (struct scratch *)pthread_getspecific(scratch_key);
    if (s == NULL) {
        s = (struct scratch *)calloc(1, sizeof *s);
        if (s == NULL || pthread_setspecific(scratch_key, s) != 0) {
            free(s);
            return NULL;
        }
    }
    if (s->size[slot] < bytes) {
        void *p = NULL;
        free(s->p[slot]);
        s->p[slot] = NULL;
        s->size[slot] = 0;
        if (posix_memalign(&p, 64, bytes) != 0)
            return NULL;
        s->p[slot] = p;
        s->size[slot] = bytes;
    }
    return s->p[slot];
}

/* Plain valves (S and J the same both ways, no drift, no lag) for up to two vectors of the widest
 * variant's lanes, taken from score's valve table (5 x m: S, J, F, y0, xs0) by plain_valve. */
typedef struct {
    double S[16], J[16], F[16], y0[16], xs0[16];
} plain_valves_t;

static const double ZEROS[16];

static inline void plain_valve(plain_valves_t *pv, int h, const double *valves, int64_t m, int64_t i)
{
    pv->S[h] = valves[i];
    pv->J[h] = valves[m + i];
    pv->F[h] = valves[2 * m + i];
    pv->y0[h] = valves[3 * m + i];
    pv->xs0[h] = valves[4 * m + i];
}

/* how score_groups_ (kernels_lanes.h) reads each lane's input */
enum { INPUT_VECTOR, INPUT_BROADCAST, INPUT_GATHER };

static int cmp_i64(const void *a, const void *b)
{
    int64_t x = *(const int64_t *)a, y = *(const int64_t *)b;
    return (x > y) - (x < y);
}

/* Closed-form SSE and gain of one (candidate, structure) from its normal-equation sums. */
static inline void finish_one(double szz, double szy, const double *szq, const double *Qty, int64_t K,
                              double yyp, double gfix, double *sse, double *gain)
{
    double zzp = szz;
    double zyp = szy;
    for (int64_t j = 0; j < K; j++) {
        zzp -= szq[j] * szq[j];
        zyp -= szq[j] * Qty[j];
    }
    if (gfix == gfix) {
        *sse = yyp - 2.0 * gfix * zyp + gfix * gfix * nmax(zzp, 0.0);
        *gain = gfix;
    } else if (zzp > 1e-10 * (szz + 1e-300) && zzp > 1e-300) {
        *sse = yyp - zyp * zyp / zzp;
        *gain = zyp / zzp;
    } else {
        *sse = yyp;
        *gain = 0.0;
    }
}

/* ---- the augmented model of `stiction explain`: after the valve ------------------------------ */

/* Solve A c = b (p x p, row-major, A and b overwritten) by Gaussian elimination with partial
 * pivoting; returns 0, or -1 for a singular matrix. */
static int solve_small(double *A, double *b, int p, double *c)
{
    for (int col = 0; col < p; col++) {
        int piv = col;
        for (int r = col + 1; r < p; r++)
            if (fabs(A[r * p + col]) > fabs(A[piv * p + col]))
                piv = r;
        if (A[piv * p + col] == 0.0)
            return -1;
        if (piv != col) {
            for (int cc = 0; cc < p; cc++) {
                double t = A[col * p + cc];
                A[col * p + cc] = A[piv * p + cc];
                A[piv * p + cc] = t;
            }
            double t = b[col];
            b[col] = b[piv];
            b[piv] = t;
        }
        for (int r = col + 1; r < p; r++) {
            double fct = A[r * p + col] / A[col * p + col];
            for (int cc = col; cc < p; cc++)
                A[r * p + cc] -= fct * A[col * p + cc];
            b[r] -= fct * b[col];
        }
    }
    for (int r = p - 1; r >= 0; r--) {
        double s = b[r];
        for (int cc = r + 1; cc < p; cc++)
            s -= A[r * p + cc] * c[cc];
        c[r] = s / A[r * p + r];
    }
    return 0;
}

#define FUSED_MAXP 16
/* samples between the exact sines and cosines of fused_load (rotations in between) */
#define LOAD_ANCHOR 64

/*
 * The augmented model after the valve: the installed characteristic c (100 (e^(c u/100) - 1) /
 * (e^c - 1), c = 0 linear), the dead time d (samples), the lags a1, a2 (< 0: first order), an
 * optional integrator, and the weighted least squares of y on [z, 1, E] (E: n x q extra columns;
 * a ridge of 1e-9 of each diagonal term keeps a singular design solvable). sgn (+1, -1; 0 free) is
 * the sign the coefficient of z must have: a fit with the other sign is refit with that coefficient
 * 0. The lanes of kernels_lanes.h run the process and the candidate's sums; the sums that do not
 * depend on the candidate (those of 1, E and y) are made once per call (`fused_fixed`), in the
 * same sample order and with the same products as a per-candidate loop would, so every candidate's
 * normal equations are the same numbers whichever way they are made.
 */
typedef struct {
    double sw, sy, syy;                        /* sum w, sum w y, sum w y y */
    double sE[FUSED_MAXP], sEy[FUSED_MAXP];    /* sum w E_j, sum (w E_j) y */
    double sEE[FUSED_MAXP * FUSED_MAXP];       /* sum (w E_j) E_l */
} fused_fixed_t;

static void fused_fixed(int64_t n, const double *E, int64_t q, const double *y, const double *w,
                        fused_fixed_t *f)
{
    memset(f, 0, sizeof(*f));
    for (int64_t k = 0; k < n; k++) {
        double wk = w[k];
        if (wk == 0.0)
            continue;
        double yk = y[k];
        f->sw += wk;
        f->sy += wk * yk;
        f->syy += wk * yk * yk;
        for (int64_t j = 0; j < q; j++) {
            double we = wk * E[k * q + j];
            f->sE[j] += we;
            f->sEy[j] += we * yk;
            for (int64_t l = 0; l < q; l++)
                f->sEE[j * q + l] += we * E[k * q + l];
        }
    }
}

/* The SSE of one candidate from its sums: szz = sum (w z) z, sz = sum w z, szy = sum (w z) y,
 * szE[j] = sum (w z) E_j, sEz[j] = sum (w E_j) z. */
static double fused_solve(double szz, double sz, double szy, const double *szE, const double *sEz,
                          const fused_fixed_t *f, int64_t q, double sgn)
{
    int p = 2 + (int)q;
    double A[FUSED_MAXP * FUSED_MAXP], b[FUSED_MAXP], coef[FUSED_MAXP];
    double Aw[FUSED_MAXP * FUSED_MAXP], bw[FUSED_MAXP], sub[FUSED_MAXP];
    A[0] = szz;
    A[1] = sz;
    A[p] = sz;
    A[p + 1] = f->sw;
    b[0] = szy;
    b[1] = f->sy;
    for (int64_t j = 0; j < q; j++) {
        int r = 2 + (int)j;
        A[r] = szE[j];
        A[r * p] = sEz[j];
        A[p + r] = f->sE[j];
        A[r * p + 1] = f->sE[j];
        b[r] = f->sEy[j];
        for (int64_t l = 0; l < q; l++)
            A[r * p + 2 + (int)l] = f->sEE[j * q + l];
    }
    double yy = f->syy;
    for (int r = 0; r < p; r++)
        A[r * p + r] += 1e-9 * (A[r * p + r] + 1e-12);
    memcpy(Aw, A, sizeof(double) * (size_t)(p * p));
    memcpy(bw, b, sizeof(double) * (size_t)p);
    if (solve_small(Aw, bw, p, coef) != 0)
        return yy;
    if (sgn != 0.0 && coef[0] * sgn < 0.0) {
        int ps = p - 1;
        for (int r = 0; r < ps; r++) {
            bw[r] = b[r + 1];
            for (int c2 = 0; c2 < ps; c2++)
                Aw[r * ps + c2] = A[(r + 1) * p + c2 + 1];
        }
        if (solve_small(Aw, bw, ps, sub) != 0)
            return yy;
        coef[0] = 0.0;
        for (int r = 1; r < p; r++)
            coef[r] = sub[r - 1];
    }
    double cb = 0.0, cac = 0.0;
    for (int r = 0; r < p; r++) {
        cb += coef[r] * b[r];
        double s = 0.0;
        for (int c2 = 0; c2 < p; c2++)
            s += A[r * p + c2] * coef[c2];
        cac += coef[r] * s;
    }
    return nmax(yy - 2.0 * cb + cac, 0.0);
}

/* The installed characteristic in place over a stem row of n samples stride apart (c = 0: left
 * linear). A stem that stays where it stuck gives the same flow: computed once per stay. */
static void characteristic_row(double *row, int64_t n, int64_t stride, double c)
{
    if (fabs(c) < 1e-9 || n <= 0)
        return;
    double den = expm1(c);
    double zp = row[0], up = 100.0 * expm1(c * zp / 100.0) / den;
    row[0] = up;
    for (int64_t k = 1; k < n; k++) {
        double z = row[k * stride];
        if (z != zp) {
            zp = z;
            up = 100.0 * expm1(c * z / 100.0) / den;
        }
        row[k * stride] = up;
    }
}

/* ---- the vectorised kernels, once per instruction set ---------------------------------------- */

#define LANES 2
#define SFX base
#define KATTR
#include "kernels_lanes.h"
#undef LANES
#undef SFX
#undef KATTR

#if defined(__x86_64__)
#define HAVE_X86_VARIANTS 1
#define LANES 4
#define SFX avx2
#define KATTR __attribute__((target("avx2")))
#include "kernels_lanes.h"
#undef LANES
#undef SFX
#undef KATTR

#define LANES 8
#define SFX avx512
#define KATTR __attribute__((target("avx512f")))
#include "kernels_lanes.h"
#undef LANES
#undef SFX
#undef KATTR
#endif

/* ---- the scalar valve: one lane ---------------------------------------------------------------- */

typedef double vec1 __attribute__((vector_size(8)));
typedef long long mask1 __attribute__((vector_size(8)));
#define VSTEP valve_step_1
#define VFRICTION valve_friction_1
#define VT vec1
#define MT mask1
#define VATTR
#include "valve_step.h"
#undef VSTEP
#undef VFRICTION
#undef VT
#undef MT
#undef VATTR

/*
 * One valve stepped one sample at a time from Python (the simulators' valves), with the operations
 * of valve_core: params = [S_up, J_up, S_dn, J_dn, dS, dJ, t0, tw, a_lag, ts] (S and J >= 0; drift
 * per second from t0 for tw seconds, actuator lag pole a_lag, sample period ts); state = [x_prev,
 * up (0/1), stuck (0/1), x_ss, f, y (stem before the lag), k (samples since the start), z (stem
 * after the lag)]. Returns z.
 */
double valve_step1(double *state, const double *params, double x)
{
    double xk = clip100(x);
    double xp = state[0];
    double v = xk - xp;
    int up_k = v > 0.0;
    int up = state[1] != 0.0;
    double k = state[6] + 1.0;
    mask1 stuck = {state[2] != 0.0 ? -1 : 0};
    vec1 xss = {state[3]}, f = {state[4]}, yp = {state[5]};
    vec1 su = {params[0]}, ju = {params[1]}, sd = {params[2]}, jd = {params[3]};
    if (params[4] != 0.0 || params[5] != 0.0)
        valve_friction_1((vec1){k * params[9]}, (vec1){params[6]}, (vec1){params[7]}, su, ju, sd, jd,
                         (vec1){params[4]}, (vec1){params[5]}, &su, &ju, &sd, &jd);
    valve_step_1(xk, xp, v == 0.0 || up_k != up, &stuck, &xss, &f, &yp, su, ju, sd, jd);
    double a = params[8];
    double z = a != 0.0 ? a * state[7] + (1.0 - a) * yp[0] : yp[0];
    state[0] = xk;
    state[1] = up_k;
    state[2] = stuck[0] ? 1.0 : 0.0;
    state[3] = xss[0];
    state[4] = f[0];
    state[5] = yp[0];
    state[6] = k;
    state[7] = z;
    return z;
}

/* The start state of valve_step1: at rest at the first input x0, or stuck at y0 (not NaN) after a
 * motion in direction f0, where the input stood at xs0 (NaN: y0 + f0 (S_f0 - J_f0) / 2). */
double valve_start1(double *state, const double *params, double x0, double f0, double y0, double xs0)
{
    double xp = clip100(x0), y = xp, s = xp;
    if (!isnan(y0)) {
        y = clip100(y0);
        double h0 = (f0 > 0 ? (params[0] - params[1]) : (params[2] - params[3])) / 2.0;
        s = isnan(xs0) ? y + f0 * h0 : xs0;
    }
    state[0] = xp;
    state[1] = 0.0;
    state[2] = 1.0;
    state[3] = s;
    state[4] = f0;
    state[5] = y;
    state[6] = 0.0;
    state[7] = y;
    return y;
}

/* S and J of both directions (out: S_up, J_up, S_dn, J_dn) t_s seconds after the first sample, for
 * params = [S_up, J_up, S_dn, J_dn, dS, dJ, t0, tw] as valve_step1's (t_s may be infinite: the
 * friction after a drift window or step). */
void valve_friction1(const double *params, double t_s, double *out)
{
    vec1 su, ju, sd, jd;
    valve_friction_1((vec1){t_s}, (vec1){params[6]}, (vec1){params[7]}, (vec1){params[0]}, (vec1){params[1]},
                     (vec1){params[2]}, (vec1){params[3]}, (vec1){params[4]}, (vec1){params[5]}, &su, &ju, &sd,
                     &jd);
    out[0] = su[0];
    out[1] = ju[0];
    out[2] = sd[0];
    out[3] = jd[0];
}

/* ---- process filters --------------------------------------------------------------------------- */

/* Unit-gain lags (+ integrator) of u -> z, starting at steady state at u[0]; a2 < 0: first order;
 * d: dead time in samples (u before the record = u[0]). */
void lag_filter(const double *u, int64_t n, double a1, double a2, int64_t d, int integ, double ts_s,
                double *z)
{
    if (n <= 0)
        return;
    double u0 = u[0];
    double z1 = u0;
    double z2 = u0;
    double acc = 0.0;
    for (int64_t k = 0; k < n; k++) {
        int64_t kd = k - d;
        double ud = kd >= 0 ? u[kd] : u0;
        z1 = a1 * z1 + (1.0 - a1) * ud;
        if (a2 >= 0.0)
            z2 = a2 * z2 + (1.0 - a2) * z1;
        else
            z2 = z1;
        if (integ) {
            acc += ts_s * z2;
            z[k] = acc;
        } else {
            z[k] = z2;
        }
    }
}

/* The noise prefilter (1 - q^-1) / (1 - a q^-1) down each column of v (n x m, leading dim ldv),
 * starting at rest at the first sample. */
void hp_filter_2d(const double *v, int64_t n, int64_t m, int64_t ldv, double a, double *out)
{
    if (n <= 0)
        return;
    for (int64_t j = 0; j < m; j++) {
        double acc = 0.0;
        double prev = v[j];
        for (int64_t k = 0; k < n; k++) {
            double vk = v[k * ldv + j];
            acc = a * acc + vk - prev;
            prev = vk;
            out[k * m + j] = acc;
        }
    }
}

/* ---- dispatch ------------------------------------------------------------------------------------ */

typedef void (*valve_run_fn)(const double *, int64_t, int64_t, const double *, const double *,
                             const double *, const double *, const double *, const double *,
                             const double *, const double *, const double *, const double *, const double *, const double *, double,
                             double *, int64_t);
typedef int (*score_fn)(const double *, int64_t, const double *, int64_t, const double *, int64_t, int, double,
                        double, const double *, const double *, const double *, int64_t, const double *, double,
                        double *, double);

static const valve_run_fn VALVE_RUN[] = {
    valve_run_base,
#ifdef HAVE_X86_VARIANTS
    valve_run_avx2, valve_run_avx512,
#endif
};
static const score_fn SCORE[] = {
    score_base,
#ifdef HAVE_X86_VARIANTS
    score_avx2, score_avx512,
#endif
};
typedef int (*fused_fn)(const double *, int64_t, int64_t, const double *, const double *, const double *,
                        const double *, const double *, const double *, const double *, const double *,
                        const double *, const double *,
                        const double *, const double *, const double *, const double *, const double *,
                        const int64_t *, const uint8_t *, double, const double *, int64_t, const double *,
                        const double *, double, double *);
static const fused_fn FUSED[] = {
    fused_base,
#ifdef HAVE_X86_VARIANTS
    fused_avx2, fused_avx512,
#endif
};
typedef int (*fused_load_fn)(const double *, int64_t, int64_t, const double *, const double *, const double *,
                             const double *, const double *, const double *, const double *, const double *,
                             const double *, const double *,
                             const double *, const double *, const double *, const double *, const double *,
                             const int64_t *, const uint8_t *, double, const double *, int, const double *,
                             const double *, double, double *);
static const fused_load_fn FUSED_LOAD[] = {
    fused_load_base,
#ifdef HAVE_X86_VARIANTS
    fused_load_avx2, fused_load_avx512,
#endif
};
static const char *const ISA_NAMES[] = {"baseline (2 lanes)", "avx2 (4 lanes)", "avx512 (8 lanes)"};

static int max_isa = -1;
static int cur_isa = 0;

static int detect_isa(void)
{
#ifdef HAVE_X86_VARIANTS
    __builtin_cpu_init();
    if (__builtin_cpu_supports("avx512f"))
        return 2;
    if (__builtin_cpu_supports("avx2"))
        return 1;
#endif
    return 0;
}

static void ensure_isa(void)
{
    if (max_isa < 0) {
        max_isa = detect_isa();
        cur_isa = max_isa;
    }
}

/* The variant for a call with `jobs` independent jobs: a narrower one when the jobs would leave
 * most lanes of the widest idle (all variants give the same numbers). */
static inline int isa_for(int64_t jobs)
{
    int lvl = cur_isa;
    if (lvl > 0 && jobs <= 2)
        lvl = 0;
    else if (lvl > 1 && jobs <= 4)
        lvl = 1;
    return lvl;
}

int kernels_abi(void) { return KERNELS_ABI; }

/* The instruction-set variant in use (0 baseline, 1 AVX2, 2 AVX-512) and the widest supported. */
int kernels_isa(void) { ensure_isa(); return cur_isa; }
int kernels_max_isa(void) { ensure_isa(); return max_isa; }
const char *kernels_isa_name(int level) { return ISA_NAMES[level < 0 ? 0 : (level > 2 ? 2 : level)]; }

/* Use a narrower variant (for tests that compare variants); returns the level in use. */
int kernels_set_isa(int level)
{
    ensure_isa();
    cur_isa = level < 0 ? 0 : (level > max_isa ? max_isa : level);
    return cur_isa;
}

void valve_run(const double *x, int64_t n, int64_t m, const double *S_up, const double *J_up,
               const double *S_dn, const double *J_dn, const double *dS, const double *dJ,
               const double *dt0, const double *dtw, const double *f0, const double *a_lag, const double *y0, const double *xs0, double ts,
               double *out, int64_t ld)
{
    ensure_isa();
    VALVE_RUN[isa_for(m)](x, n, m, S_up, J_up, S_dn, J_dn, dS, dJ, dt0, dtw, f0, a_lag, y0, xs0, ts, out, ld);
}

int score(const double *x, int64_t n, const double *valves, int64_t m, const double *structs, int64_t P,
          int paired, double ts, double ahp, const double *w, const double *yw, const double *Qw, int64_t K,
          const double *Qty, double yyp, double *out, double gfix)
{
    ensure_isa();
    return SCORE[isa_for(paired ? m : m * P)](x, n, valves, m, structs, P, paired, ts, ahp, w, yw, Qw, K, Qty,
                                               yyp, out, gfix);
}

/*
 * Training SSE of m candidate augmented models (`stiction explain`): the valve (valve_step.h, per
 * direction S and J drifting linearly in time within the window dt0 .. dt0 + dtw (NULL: the whole
 * record; dtw one sample: a step), actuator lag a_lag, start y0 / xs0), run LANES
 * candidates at a time, then their process and sums in the same lanes. Returns 0, or -1 when memory runs out or
 * q is too large.
 */
int fused_sse(const double *x, int64_t n, int64_t m, const double *S_up, const double *J_up,
              const double *S_dn, const double *J_dn, const double *dS, const double *dJ,
              const double *dt0, const double *dtw, const double *f0, const double *a_lag, const double *y0, const double *xs0,
              const double *cc, const double *a1, const double *a2, const int64_t *d,
              const uint8_t *integ, double ts_s, const double *E, int64_t q, const double *y,
              const double *w, double sgn, double *out)
{
    ensure_isa();
    return FUSED[isa_for(m)](x, n, m, S_up, J_up, S_dn, J_dn, dS, dJ, dt0, dtw, f0, a_lag, y0, xs0, cc, a1, a2, d, integ,
                             ts_s, E, q, y, w, sgn, out);
}

/*
 * fused_sse with each candidate's own sinusoidal load (wload, rad/s) as the extra columns, after a
 * time column when with_t (an integrating process): [z, 1, (t), sin(w t), cos(w t)]. Returns 0, or -1
 * when memory runs out.
 */
int fused_sse_load(const double *x, int64_t n, int64_t m, const double *S_up, const double *J_up,
                   const double *S_dn, const double *J_dn, const double *dS, const double *dJ,
                   const double *dt0, const double *dtw, const double *f0, const double *a_lag, const double *y0, const double *xs0,
                   const double *cc, const double *a1, const double *a2, const int64_t *d,
                   const uint8_t *integ, double ts_s, const double *wload, int with_t, const double *y,
                   const double *w, double sgn, double *out)
{
    ensure_isa();
    return FUSED_LOAD[isa_for(m)](x, n, m, S_up, J_up, S_dn, J_dn, dS, dJ, dt0, dtw, f0, a_lag, y0, xs0, cc, a1, a2, d, integ,
                                  ts_s, wload, with_t, y, w, sgn, out);
}

/* ---- signal helpers of the evidence tests (diagnose/evidence/_signals.py, stuck.py) ------------- */

/*
 * A cascade of second-order sections over x, in place, from the section states zi (n_sections x 2,
 * updated): transposed direct form II, in the operation order of scipy.signal.sosfilt. sos rows are
 * [b0, b1, b2, a0, a1, a2] with a0 = 1.
 */
void sosfilt(const double *sos, int64_t n_sections, double *x, int64_t n, double *zi)
{
    for (int64_t i = 0; i < n; i++) {
        double x_cur = x[i];
        for (int64_t s = 0; s < n_sections; s++) {
            const double *c = sos + 6 * s;
            double *z = zi + 2 * s;
            double x_new = c[0] * x_cur + z[0];
            z[0] = c[1] * x_cur - c[4] * x_new + z[1];
            z[1] = c[2] * x_cur - c[5] * x_new;
            x_cur = x_new;
        }
        x[i] = x_cur;
    }
}

/*
 * The local maxima of x (a flat top counts once, at its middle, rounded down) and each one's
 * prominence over the whole record: its height above the higher of the lowest points between it
 * and the nearest higher sample on either side (the definition of scipy.signal.peak_prominences).
 * Writes at most n indices and prominences; returns how many.
 */
int64_t peak_prominences(const double *x, int64_t n, int64_t *peaks, double *prom)
{
    int64_t m = 0;
    int64_t i = 1;
    while (i < n - 1) {
        if (x[i - 1] < x[i]) {
            int64_t ahead = i + 1;
            while (ahead < n - 1 && x[ahead] == x[i])
                ahead++;
            if (x[ahead] < x[i]) {
                peaks[m++] = (i + ahead - 1) / 2;
                i = ahead;
            }
        }
        i++;
    }
    for (int64_t k = 0; k < m; k++) {
        int64_t p = peaks[k];
        double top = x[p];
        double left_min = top, right_min = top;
        for (int64_t j = p; j >= 0 && x[j] <= top; j--)
            if (x[j] < left_min)
                left_min = x[j];
        for (int64_t j = p; j < n && x[j] <= top; j++)
            if (x[j] < right_min)
                right_min = x[j];
        prom[k] = top - nmax(left_min, right_min);
    }
    return m;
}

/* ---- a Python module, so that pip builds and installs this file as an extension ---------------- */

static struct PyModuleDef kernels_module = {
    PyModuleDef_HEAD_INIT,
    .m_name = "_kernels",
    .m_doc = "Compiled kernels of the stiction diagnostics; loaded with ctypes by diagnose.kernels.",
    .m_size = -1,
};

PyMODINIT_FUNC PyInit__kernels(void) { return PyModule_Create(&kernels_module); }
