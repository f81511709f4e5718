/*
 * Native twins of the numba kernels on the identification path (see diagnose/native/__init__.py).
 *
 * Each function is a line-by-line port of the numba kernel named in its comment and performs the
 * same floating-point operations in the same order, so that, compiled without -ffast-math and with
 * -ffp-contract=off (no fused multiply-add), it returns the same numbers bit for bit:
 *
 *   stiction_batch  <- diagnose.stiction_model._batch_kernel
 *   valve_smooth    <- diagnose.output_error._valve_smooth
 *   lag_filter      <- diagnose.process_model._lag_filter
 *   hp_filter_2d    <- diagnose.output_error._hp_filter_2d
 *   ham_sse         <- diagnose.output_error._ham_sse (each job as diagnose.output_error._one_structure)
 *
 * min/max follow numba's (and Python's) builtins: max(a, b) = b > a ? b : a,
 * min(a, b) = b < a ? b : a.
 *
 * Arrays are C-contiguous float64 (int64 for delays, one byte per bool); 2-D arrays are passed with
 * their leading dimension (elements per row). The Python side checks shapes before calling.
 */
#include <stdint.h>
#include <stdlib.h>

#define NATIVE_ABI_VERSION 1

int stiction_native_abi(void) { return NATIVE_ABI_VERSION; }

/* LANES doubles operated on element by element (GCC/clang vector extension: plain IEEE operations,
 * lowered to whatever vector width the target has). Eight lanes (two AVX registers) keep two
 * independent sets of recursions in flight; on the identification workload they beat four by
 * about 10 % (sixteen spill registers and are four times slower). */
#ifndef LANES
#define LANES 8
#endif
typedef double vec __attribute__((vector_size(8 * LANES)));

static inline double nmax(double a, double b) { return b > a ? b : a; }
static inline double nmin(double a, double b) { return b < a ? b : a; }
static inline double clip100(double v) { return nmin(nmax(v, 0.0), 100.0); }

/* One candidate valve of the two-parameter stiction model over x[0..n); output to out[0..n). */
static void stiction_one(const double *x, int64_t n, double s, double j, double f, double *out)
{
    /* f is +-1, so f * half equals f * (s - j) / 2 exactly, as in the reference. */
    double half = (s - j) / 2.0;
    double xp = clip100(x[0]);
    int up = 0;
    double yp = xp;
    double xss = xp;
    int stuck = 1;
    out[0] = yp;
    for (int64_t k = 1; k < n; k++) {
        double xk = clip100(x[k]);
        double v = xk - xp;
        int up_k = v > 0.0;
        if (!stuck && (v == 0.0 || up_k != up)) {
            stuck = 1;
            xss = xp;
        }
        if (stuck) {
            double d = xk - xss;
            if (-f * d > s) {
                f = -f;
                stuck = 0;
                yp = clip100(xk - f * half);
            } else if (f * d > j) {
                stuck = 0;
                yp = clip100(xk - f * half);
            }
        } else {
            yp = clip100(xk - f * half);
        }
        out[k] = yp;
        xp = xk;
        up = up_k;
    }
}

/* diagnose.stiction_model._batch_kernel: m candidates (S, J, f0) -> out (m rows, leading dim ld). */
void stiction_batch(const double *x, int64_t n, const double *S, const double *J, const double *f0,
                    int64_t m, double *out, int64_t ld)
{
    if (n <= 0)
        return;
    for (int64_t i = 0; i < m; i++)
        stiction_one(x, n, S[i], J[i], f0[i], out + i * ld);
}

typedef long long veci __attribute__((vector_size(8 * LANES)));

/* Lane-wise select: m ? a : b (m is all ones or all zeros per lane, from a comparison). */
static inline vec vsel(veci m, vec a, vec b) { return (vec)(((veci)a & m) | ((veci)b & ~m)); }

/* clip100 lane by lane, with the same comparisons as nmax/nmin. */
static inline vec vclip100(vec v)
{
    const vec lo = (vec){0.0} + 0.0, hi = (vec){0.0} + 100.0;
    vec t = vsel(lo > v, lo, v);
    return vsel(hi < t, hi, t);
}

/*
 * LANES candidate valves over the same input at once, without branches per lane: exactly the
 * operations of stiction_one in each lane (the input, its increment and direction are shared;
 * the state and the thresholds are per lane). Lane g writes out[g][0..n).
 */
static void stiction_lanes(const double *x, int64_t n, const double s_[LANES], const double j_[LANES],
                          const double f_[LANES], double *out[LANES])
{
    vec s, j, f;
    for (int g = 0; g < LANES; g++) {
        s[g] = s_[g];
        j[g] = j_[g];
        f[g] = f_[g];
    }
    vec half = (s - j) / 2.0;
    double xp = clip100(x[0]);
    int up = 0;
    vec yp = (vec){0.0} + xp;
    vec xss = yp;
    veci stuck = (veci){0} - 1;
    for (int g = 0; g < LANES; g++)
        out[g][0] = xp;
    for (int64_t k = 1; k < n; k++) {
        double xk = clip100(x[k]);
        double v = xk - xp;
        int up_k = v > 0.0;
        if (v == 0.0 || up_k != up) {
            /* every moving lane stops at the previous input */
            vec xp4 = (vec){0.0} + xp;
            xss = vsel(stuck, xss, xp4);
            stuck = (veci){0} - 1;
        }
        vec xk4 = (vec){0.0} + xk;
        vec d = xk4 - xss;
        veci rev = stuck & ((-f) * d > s);
        veci fwd = stuck & ~rev & (f * d > j);
        f = vsel(rev, -f, f);
        veci move = ~stuck | rev | fwd;
        stuck = stuck & ~(rev | fwd);
        yp = vsel(move, vclip100(xk4 - f * half), yp);
        for (int g = 0; g < LANES; g++)
            out[g][k] = yp[g];
        xp = xk;
        up = up_k;
    }
}

/* diagnose.output_error._valve_smooth: the valve with the slip instant interpolated inside the sample. */
void valve_smooth(const double *x, int64_t n, double s, double j, double f0, double *out)
{
    if (n <= 0)
        return;
    double half = (s - j) / 2.0;
    double f = f0;
    double xp = clip100(x[0]);
    int up = 0;
    double yp = xp;
    double xss = xp;
    int stuck = 1;
    out[0] = yp;
    for (int64_t k = 1; k < n; k++) {
        double xk = clip100(x[k]);
        double v = xk - xp;
        int up_k = v > 0.0;
        if (!stuck && (v == 0.0 || up_k != up)) {
            stuck = 1;
            xss = xp;
        }
        if (stuck) {
            double d = xk - xss;
            double thr = 0.0;
            int moved = 0;
            if (-f * d > s) {
                f = -f;
                stuck = 0;
                thr = xss + f * s;
                moved = 1;
            } else if (f * d > j) {
                stuck = 0;
                thr = xss + f * j;
                moved = 1;
            }
            if (moved) {
                double ynew = clip100(xk - f * half);
                double frac = v != 0.0 ? (xk - thr) / v : 1.0;
                frac = nmin(nmax(frac, 0.0), 1.0);
                out[k] = yp + frac * (ynew - yp);
                yp = ynew;
            } else {
                out[k] = yp;
            }
        } else {
            yp = clip100(xk - f * half);
            out[k] = yp;
        }
        xp = xk;
        up = up_k;
    }
}

/* diagnose.process_model._lag_filter: unit-gain lags (+ integrator) of u -> z; a2 < 0: first order. */
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

/* diagnose.output_error._hp_filter_2d: (1 - q^-1) / (1 - a q^-1) down each column of v (n x m). */
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

/*
 * diagnose.output_error._ham_sse: output-error SSE (and gain) of every (valve candidate i, structure p).
 * sse and gain are m x P (row-major). Returns 0, or -1 when memory runs out.
 *
 * The numba kernel runs four structures of one candidate at a time and the leftover structures one
 * by one. Here the m * P (candidate, structure) jobs are taken LANES at a time in the order
 * (i, p), whatever candidates they belong to, so that a search over one structure (P = 1, the
 * simplex refinement) also keeps several recursions in flight. Each job performs exactly the
 * operations of `_one_structure` (which are those of one lane of numba's four-structure loop), so
 * every entry equals numba's bit for bit. The valve outputs of the (at most LANES) candidates of a group are
 * kept in LANES buffers and computed once per candidate (several at once by stiction_lanes).
 */
int ham_sse(const double *x, int64_t n, const double *S, const double *J, const double *F, int64_t m,
            const double *a1, const double *a2, const int64_t *d, const uint8_t *integ, int64_t P,
            double ts, double ahp, const double *w, const double *yw, const double *Qw, int64_t K,
            const double *Qty, double yyp, double *sse, double *gain, int smooth, double gfix)
{
    if (m <= 0 || P <= 0)
        return 0;
    int64_t nb = n > 0 ? n : 1;
    double *ubuf = (double *)malloc(sizeof(double) * (size_t)(LANES * nb));
    double *szq = (double *)malloc(sizeof(double) * (size_t)(K > 0 ? K : 1));
    vec sq[K > 0 ? K : 1];       /* Q'z sums of the group's jobs (on the stack: aligned) */
    if (ubuf == NULL || szq == NULL) {
        free(ubuf);
        free(szq);
        return -1;
    }
    int64_t owner[LANES];       /* candidate whose valve output buffer b holds */
    for (int b = 0; b < LANES; b++) {
        owner[b] = -1;
        ubuf[b * nb] = 0.0;
    }
    int hp = ahp >= 0.0;
    int64_t njobs = m * P;
    for (int64_t t0 = 0; t0 < njobs; t0 += LANES) {
        int64_t ci[LANES], pi[LANES];
        const double *ug_ptr[LANES];
        double u0[LANES];
        for (int g = 0; g < LANES; g++) {
            int64_t t = t0 + g < njobs ? t0 + g : njobs - 1;     /* pad the last group */
            ci[g] = t / P;
            pi[g] = t % P;
        }
        /* valve outputs: keep buffers of candidates still needed, fill the others */
        int used[LANES] = {0};
        int buf_of[LANES];
        for (int g = 0; g < LANES; g++) {
            buf_of[g] = -1;
            for (int b = 0; b < LANES; b++)
                if (owner[b] == ci[g]) {
                    buf_of[g] = b;
                    used[b] = 1;
                }
        }
        int nneed = 0;
        int64_t need_i[LANES];
        double *need_u[LANES];
        for (int g = 0; g < LANES; g++) {
            if (buf_of[g] >= 0)
                continue;
            int b = 0;
            while (used[b])
                b++;
            int64_t i = ci[g];
            owner[b] = i;
            used[b] = 1;
            need_i[nneed] = i;
            need_u[nneed] = ubuf + b * nb;
            nneed++;
            for (int h = g; h < LANES; h++)
                if (ci[h] == i)
                    buf_of[h] = b;
        }
        if (nneed >= 2 && !smooth && n > 0) {
            /* several new candidates: one pass for all (spare lanes repeat the first) */
            double s4[LANES], j4[LANES], f4[LANES];
            double *o4[LANES];
            for (int g = 0; g < LANES; g++) {
                int h = g < nneed ? g : 0;
                s4[g] = S[need_i[h]];
                j4[g] = J[need_i[h]];
                f4[g] = F[need_i[h]];
                o4[g] = need_u[h];
            }
            stiction_lanes(x, n, s4, j4, f4, o4);
        } else {
            for (int h = 0; h < nneed; h++) {
                int64_t i = need_i[h];
                if (smooth)
                    valve_smooth(x, n, S[i], J[i], F[i], need_u[h]);
                else
                    stiction_batch(x, n, S + i, J + i, F + i, 1, need_u[h], n);
            }
        }
        vec A1, B1, A2, B2, I, N;
        int64_t D[LANES];
        for (int g = 0; g < LANES; g++) {
            int64_t p = pi[g];
            ug_ptr[g] = ubuf + buf_of[g] * nb;
            u0[g] = ug_ptr[g][0];
            A1[g] = a1[p];
            B1[g] = 1.0 - A1[g];
            A2[g] = nmax(a2[p], 0.0);
            B2[g] = 1.0 - A2[g];
            I[g] = integ[p] ? ts : 0.0;
            N[g] = integ[p] ? 0.0 : 1.0;
            D[g] = d[p];
        }
        vec z1 = {0.0}, z2 = z1, ac = z1, pr = z1, fh = z1, sz = z1, sy = z1;
        vec ahp4 = z1 + ahp;
        for (int64_t j = 0; j < K; j++)
            sq[j] = z1;
        for (int64_t k = 0; k < n; k++) {
            vec ug;
            for (int g = 0; g < LANES; g++) {
                int64_t kk = k - D[g];
                ug[g] = kk >= 0 ? (ug_ptr[g][kk] - u0[g]) : 0.0;
            }
            z1 = A1 * z1 + B1 * ug;
            z2 = A2 * z2 + B2 * z1;
            ac += I * z2;
            vec v = N * z2 + ac;
            if (hp) {
                fh = ahp4 * fh + v - pr;
                pr = v;
                v = fh;
            }
            double wk = w[k];
            if (wk != 0.0) {
                double yk = yw[k];
                sz += wk * v * v;
                sy += yk * v;
                const double *qrow = Qw + k * K;
                for (int64_t j = 0; j < K; j++)
                    sq[j] += qrow[j] * v;
            }
        }
        for (int g = 0; g < LANES && t0 + g < njobs; g++) {
            for (int64_t j = 0; j < K; j++)
                szq[j] = sq[j][g];
            int64_t at = ci[g] * P + pi[g];
            finish_one(sz[g], sy[g], szq, Qty, K, yyp, gfix, &sse[at], &gain[at]);
        }
    }
    free(ubuf);
    free(szq);
    return 0;
}
