/*
 * The vectorised kernels for one instruction set: included by kernels.c once per variant with
 * LANES (doubles per vector), SFX (name suffix) and KATTR (target attribute) defined.
 *
 * Lanes run independent jobs (candidate valves, or candidate x process-structure pairs) over the
 * same input, each lane doing exactly the operations the scalar model prescribes, so a job's result
 * is the same whatever the width and whichever other jobs share its vector.
 */
#define V_(a, b) a##b
#define V(a, b) V_(a, b)
#define VT V(vec, SFX)
#define MT V(mask, SFX)

typedef double VT __attribute__((vector_size(8 * LANES)));
typedef long long MT __attribute__((vector_size(8 * LANES)));

#define VSTEP V(valve_step_, SFX)
#define VFRICTION V(valve_friction_, SFX)
#define VATTR KATTR
#include "valve_step.h"
#undef VSTEP
#undef VFRICTION
#undef VATTR

/* clip each lane to >= 0 (S and J are never negative, also while drifting) */
static inline __attribute__((always_inline)) KATTR VT V(nonneg_, SFX)(VT v)
{
    VT z = (VT){0.0};
    return (VT)(((MT)z & (z > v)) | ((MT)v & ~(z > v)));
}

/*
 * nv (1 or 2) vectors of LANES candidate valves over x[0..n): lane g of vector u (its parameters at
 * index u * LANES + g) has stiction (su, ju) opening and (sd, jd) closing, drift (ds, dj) per
 * second from t0 for tw seconds (t0_ / tw_ NULL: from the start, for ever), starting direction
 * f, actuator lag pole a (0: none) and start state y0 / xs0 (NaN: at rest at the first input).
 * With vec it writes all lanes' (lagged) stems of sample k as the one
 * vector il[u][k]; without (nv = 1 only), lane g's stem to rows[g][0..n). Two vectors advance side
 * by side (the step is a chain of dependent operations); each lane does the same operations either
 * way. valve_lanes and valve_lanes_vec below are the one-vector forms.
 */
static inline __attribute__((always_inline)) KATTR void V(valve_core_, SFX)(
    const int nv, const double *x, int64_t n, const double *su_, const double *ju_, const double *sd_,
    const double *jd_, const double *ds_, const double *dj_, const double *t0_, const double *tw_,
    const double *f_, const double *a_,
    const double *y0_, const double *xs0_, double ts, double **rows, VT *const *il, const int vec)
{
    VT su0[2], ju0[2], sd0[2], jd0[2], ds[2], dj[2], f[2], a[2], yp[2], xss[2], z[2];
    VT su[2], ju[2], sd[2], jd[2], t0[2], tw[2];
    MT stuck[2];
    int drift[2] = {0, 0}, lag[2] = {0, 0};
    double xp = clip100(x[0]);
    for (int u = 0; u < nv; u++) {
        const double *src[] = {su_, ju_, sd_, jd_, ds_, dj_, f_, a_};
        VT *dst[] = {&su0[u], &ju0[u], &sd0[u], &jd0[u], &ds[u], &dj[u], &f[u], &a[u]};
        for (int r = 0; r < 8; r++)
            memcpy(dst[r], src[r] + u * LANES, sizeof(VT));
        for (int g = 0; g < LANES; g++) {
            if (ds[u][g] != 0.0 || dj[u][g] != 0.0)
                drift[u] = 1;
            if (a[u][g] != 0.0)
                lag[u] = 1;
        }
        /* the drift runs from t0 for tw seconds (none given: from the start, for ever) */
        double t0a[LANES], twa[LANES];
        for (int g = 0; g < LANES; g++) {
            t0a[g] = t0_ != NULL ? t0_[u * LANES + g] : 0.0;
            twa[g] = tw_ != NULL ? tw_[u * LANES + g] : INFINITY;
        }
        memcpy(&t0[u], t0a, sizeof(VT));
        memcpy(&tw[u], twa, sizeof(VT));
        su[u] = V(nonneg_, SFX)(su0[u]);
        ju[u] = V(nonneg_, SFX)(ju0[u]);
        sd[u] = V(nonneg_, SFX)(sd0[u]);
        jd[u] = V(nonneg_, SFX)(jd0[u]);
        double ya[LANES], xa[LANES];
        for (int g = 0; g < LANES; g++) {
            double y = xp, st = xp, y0 = y0_[u * LANES + g], xs0 = xs0_[u * LANES + g];
            if (!isnan(y0)) {
                /* stuck at y0 after a motion in direction f: the input stood at y0 + f (S_f - J_f) / 2 */
                y = clip100(y0);
                double h0 = (f[u][g] > 0 ? (su[u][g] - ju[u][g]) : (sd[u][g] - jd[u][g])) / 2.0;
                st = y + f[u][g] * h0;
                if (!isnan(xs0))
                    st = xs0;
            }
            ya[g] = y;
            xa[g] = st;
        }
        memcpy(&yp[u], ya, sizeof(VT));
        memcpy(&xss[u], xa, sizeof(VT));
        z[u] = yp[u];
        if (vec)
            il[u][0] = z[u];
        else
            for (int g = 0; g < LANES; g++)
                rows[g][0] = z[u][g];
        stuck[u] = (MT){0} - 1;
    }
    int up = 0;
    for (int64_t k = 1; k < n; k++) {
        double xk = clip100(x[k]);
        double v = xk - xp;
        int up_k = v > 0.0;
        int stop = v == 0.0 || up_k != up;
        for (int u = 0; u < nv; u++) {
            if (drift[u]) {
                /* the friction at this sample */
                V(valve_friction_, SFX)((VT){0.0} + (double)k * ts, t0[u], tw[u], su0[u], ju0[u], sd0[u], jd0[u],
                                        ds[u], dj[u], &su[u], &ju[u], &sd[u], &jd[u]);
            }
            V(valve_step_, SFX)(xk, xp, stop, &stuck[u], &xss[u], &f[u], &yp[u], su[u], ju[u], sd[u], jd[u]);
            z[u] = lag[u] ? a[u] * z[u] + (1.0 - a[u]) * yp[u] : yp[u];
            if (vec)
                il[u][k] = z[u];
            else
                for (int g = 0; g < LANES; g++)
                    rows[g][k] = z[u][g];
        }
        xp = xk;
        up = up_k;
    }
}

static KATTR void V(valve_lanes_, SFX)(const double *x, int64_t n, const double *su, const double *ju,
                                        const double *sd, const double *jd, const double *ds, const double *dj,
                                        const double *t0, const double *tw, const double *f, const double *a,
                                        const double *y0, const double *xs0, double ts, double **rows)
{
    V(valve_core_, SFX)(1, x, n, su, ju, sd, jd, ds, dj, t0, tw, f, a, y0, xs0, ts, rows, NULL, 0);
}

/* valve_lanes writing all lanes' stems of sample k as the one vector il[k] */
static KATTR void V(valve_lanes_vec_, SFX)(const double *x, int64_t n, const double *su, const double *ju,
                                            const double *sd, const double *jd, const double *ds,
                                            const double *dj, const double *t0, const double *tw,
                                            const double *f, const double *a, const double *y0,
                                            const double *xs0, double ts, VT *il)
{
    V(valve_core_, SFX)(1, x, n, su, ju, sd, jd, ds, dj, t0, tw, f, a, y0, xs0, ts, NULL, &il, 1);
}

/* m candidate valves (arrays of m) -> out (m rows, leading dimension ld); see valve_lanes. */
KATTR void V(valve_run_, SFX)(const double *x, int64_t n, int64_t m, const double *S_up, const double *J_up,
                              const double *S_dn, const double *J_dn, const double *dS, const double *dJ,
                              const double *dt0, const double *dtw, const double *f0, const double *a_lag,
                              const double *y0, const double *xs0,
                              double ts, double *out, int64_t ld)
{
    if (n <= 0)
        return;
    for (int64_t i0 = 0; i0 < m; i0 += LANES) {
        double su[LANES], ju[LANES], sd[LANES], jd[LANES], ds[LANES], dj[LANES], f[LANES], a[LANES];
        double y[LANES], s[LANES], t0[LANES], tw[LANES];
        double *rows[LANES];
        for (int g = 0; g < LANES; g++) {
            int64_t i = i0 + g < m ? i0 + g : m - 1;        /* spare lanes repeat the last valve */
            su[g] = S_up[i]; ju[g] = J_up[i]; sd[g] = S_dn[i]; jd[g] = J_dn[i];
            ds[g] = dS[i]; dj[g] = dJ[i]; f[g] = f0[i]; a[g] = a_lag[i]; y[g] = y0[i]; s[g] = xs0[i];
            t0[g] = dt0 != NULL ? dt0[i] : 0.0;
            tw[g] = dtw != NULL ? dtw[i] : INFINITY;
            rows[g] = out + i * ld;
        }
        V(valve_lanes_, SFX)(x, n, su, ju, sd, jd, ds, dj, t0, tw, f, a, y, s, ts, rows);
    }
}

/* lane g's process coefficients for structure p of a score call: lags a1 and a2 (a2 < 0: first
 * order, taken as z2 = z1), the integrator's step and the weight of the lag output */
static inline __attribute__((always_inline)) KATTR void V(proc_lane_, SFX)(
    int g, int64_t p, const double *a1, const double *a2, const double *integ, double ts, VT *A1, VT *B1,
    VT *A2, VT *B2, VT *I, VT *N)
{
    (*A1)[g] = a1[p];
    (*B1)[g] = 1.0 - (*A1)[g];
    (*A2)[g] = nmax(a2[p], 0.0);
    (*B2)[g] = 1.0 - (*A2)[g];
    (*I)[g] = integ[p] != 0.0 ? ts : 0.0;
    (*N)[g] = integ[p] != 0.0 ? 0.0 : 1.0;
}

/* The process, noise prefilter and normal-equation sums of ng (1 or 2) groups of LANES jobs. Each
 * lane's input at sample k is read by `mode`: INPUT_VECTOR, lane-interleaved (in[u][k] holds all
 * lanes' inputs); INPUT_BROADCAST, one row for all lanes (gp[u * LANES][k]); INPUT_GATHER, a row
 * per lane (gp[u * LANES + g][k]), a scalar load per lane, the slowest. Two groups advance side by
 * side: each lane's recursion is a chain of dependent operations, and a second independent chain
 * fills the cycles the first waits on. Every lane does the same operations in the same order
 * whatever the mode and the grouping, so the results are the same bit for bit. */
static inline __attribute__((always_inline)) KATTR void V(score_groups_, SFX)(
    const int ng, const int mode, int64_t n, const VT *const *in, const double *const *gp, const VT *A1,
    const VT *B1, const VT *A2, const VT *B2, const VT *I, const VT *N, int hp, double ahp, const double *w,
    const double *yw, const double *Qw, int64_t K, VT *sz_out, VT *sy_out, VT *sq_out)
{
    VT z1[2], z2[2], ac[2], pr[2], fh[2], sz[2], sy[2];
    VT sq[2 * (K > 0 ? K : 1)];
    VT zero = {0.0};
    VT ahpv = zero + ahp;
    for (int u = 0; u < ng; u++) {
        z1[u] = z2[u] = ac[u] = pr[u] = fh[u] = sz[u] = sy[u] = zero;
        for (int64_t j = 0; j < K; j++)
            sq[u * K + j] = zero;
    }
    for (int64_t k = 0; k < n; k++) {
        double wk = w[k];
        double yk = yw[k];
        const double *qrow = Qw + k * K;
        for (int u = 0; u < ng; u++) {
            VT ug;
            if (mode == INPUT_VECTOR)
                ug = in[u][k];
            else if (mode == INPUT_BROADCAST)
                ug = zero + gp[u * LANES][k];
            else
                for (int g = 0; g < LANES; g++)
                    ug[g] = gp[u * LANES + g][k];
            z1[u] = A1[u] * z1[u] + B1[u] * ug;
            z2[u] = A2[u] * z2[u] + B2[u] * z1[u];
            ac[u] += I[u] * z2[u];
            VT v = N[u] * z2[u] + ac[u];
            if (hp) {
                fh[u] = ahpv * fh[u] + v - pr[u];
                pr[u] = v;
                v = fh[u];
            }
            if (wk != 0.0) {
                sz[u] += wk * v * v;
                sy[u] += yk * v;
                for (int64_t j = 0; j < K; j++)
                    sq[u * K + j] += qrow[j] * v;
            }
        }
    }
    for (int u = 0; u < ng; u++) {
        sz_out[u] = sz[u];
        sy_out[u] = sy[u];
        for (int64_t j = 0; j < K; j++)
            sq_out[u * K + j] = sq[u * K + j];
    }
}

/* process chains side by side only where the registers hold both (AVX-512 has 32, the others 16);
 * two valve vectors side by side pay on every variant */
#undef BLOCK_GROUPS
#undef BLOCK_VALVES
#define BLOCK_GROUPS (LANES >= 8 ? 2 : 1)
#define BLOCK_VALVES 2

/*
 * score_ for m >= LANES candidates: LANES candidates share one valve pass, written lane-interleaved,
 * and then each structure's pass over them reads one vector per sample (all lanes have that
 * structure's dead time) instead of gathering a scalar per lane. Same arguments and results.
 */
static KATTR int V(score_blocks_, SFX)(const double *x, int64_t n, const double *valves, int64_t m,
                                        const double *structs, int64_t P, double ts, double ahp, const double *w,
                                        const double *yw, const double *Qw, int64_t K, const double *Qty,
                                        double yyp, double *out, double gfix)
{
    const double *a1 = structs, *a2 = structs + P, *dd = structs + 2 * P, *integ = structs + 3 * P;
    double *sse = out, *gain = out + m * P;
    int64_t dmax = 0;
    for (int64_t p = 0; p < P; p++)
        if ((int64_t)dd[p] > dmax)
            dmax = (int64_t)dd[p];
    int64_t Kq = K > 0 ? K : 1;
    VT sq[2 * Kq];
    double szq[Kq];
    VT *il = (VT *)scratch(SCRATCH_ROWS, sizeof(VT) * (size_t)(2 * (n + dmax)));
    if (il == NULL)
        return -1;
    VT zero = {0.0};
    for (int64_t k = 0; k < dmax; k++)
        il[k] = il[n + dmax + k] = zero;    /* the input before the record, through a dead time */
    VT *rows[2] = {il + dmax, il + (n + dmax) + dmax};
    int hp = ahp >= 0.0;
    for (int64_t i0 = 0; i0 < m; i0 += BLOCK_VALVES * LANES) {
        int nv = BLOCK_VALVES == 2 && m - i0 > LANES ? 2 : 1;
        plain_valves_t pv;
        for (int h = 0; h < nv * LANES; h++)
            plain_valve(&pv, h, valves, m, i0 + h < m ? i0 + h : m - 1);    /* spare lanes repeat the last */
        if (nv == 2)
            V(valve_core_, SFX)(2, x, n, pv.S, pv.J, pv.S, pv.J, ZEROS, ZEROS, NULL, NULL, pv.F, ZEROS, pv.y0,
                                pv.xs0, ts, NULL,
                                rows, 1);
        else
            V(valve_core_, SFX)(1, x, n, pv.S, pv.J, pv.S, pv.J, ZEROS, ZEROS, NULL, NULL, pv.F, ZEROS, pv.y0,
                                pv.xs0, ts, NULL,
                                rows, 1);
        for (int u = 0; u < nv; u++) {
            VT first = rows[u][0];
            for (int64_t k = 0; k < n; k++)
                rows[u][k] -= first;
        }
        /* the jobs (valve vector u, structure p) in (p, u) order, BLOCK_GROUPS at a time */
        int64_t nj = nv * P;
        for (int64_t q0 = 0; q0 < nj; q0 += BLOCK_GROUPS) {
            int ng = BLOCK_GROUPS == 2 && nj - q0 > 1 ? 2 : 1;
            VT A1[2], B1[2], A2[2], B2[2], I[2], N[2], sz[2], sy[2];
            const VT *in[2];
            int uu[2];
            int64_t pp[2];
            for (int r = 0; r < ng; r++) {
                int64_t p = (q0 + r) / nv;
                int u = (int)((q0 + r) % nv);
                uu[r] = u;
                pp[r] = p;
                in[r] = rows[u] - (int64_t)dd[p];
                VT ca1, cb1, ca2, cb2, ci, cn;
                for (int g = 0; g < LANES; g++)
                    V(proc_lane_, SFX)(g, p, a1, a2, integ, ts, &ca1, &cb1, &ca2, &cb2, &ci, &cn);
                A1[r] = ca1;
                B1[r] = cb1;
                A2[r] = ca2;
                B2[r] = cb2;
                I[r] = ci;
                N[r] = cn;
            }
            if (ng == 2)
                V(score_groups_, SFX)(2, INPUT_VECTOR, n, in, NULL, A1, B1, A2, B2, I, N, hp, ahp, w, yw, Qw, K,
                                      sz, sy, sq);
            else
                V(score_groups_, SFX)(1, INPUT_VECTOR, n, in, NULL, A1, B1, A2, B2, I, N, hp, ahp, w, yw, Qw, K,
                                      sz, sy, sq);
            for (int r = 0; r < ng; r++)
                for (int g = 0; g < LANES && i0 + uu[r] * LANES + g < m; g++) {
                    for (int64_t j = 0; j < K; j++)
                        szq[j] = sq[r * K + j][g];
                    int64_t at = (i0 + uu[r] * LANES + g) * P + pp[r];
                    finish_one(sz[r][g], sy[r][g], szq, Qty, K, yyp, gfix, &sse[at], &gain[at]);
                }
        }
    }
    return 0;
}

/*
 * Output-error scoring of every (valve candidate i, process structure p).
 *
 * valves is 5 x m: rows S, J, F (starting direction) and the start state y0, xs0 of valve_lanes
 * (NaN: at rest at x[0]); structs is 4 x P: rows a1, a2 (lag poles, a2 < 0: first order), the dead
 * time in samples and the integrator flag; out is 2 x m x P: the SSE, then the gain (row-major).
 * The valve of candidate i drives the unit-gain structure p, taken relative to the valve's first
 * position; the noise prefilter (ahp >= 0) follows; the weighted normal-equation sums against the
 * data yw and the orthonormal load basis Qw (n x K) give the SSE after the load and the gain are
 * solved (closed form in finish_one; gfix: a fixed gain, NaN: free).
 * With at least LANES candidates the work goes to score_blocks_. Otherwise the m * P jobs run LANES
 * at a time, each candidate's structures in order of dead time (lanes that read the same row read
 * it once); a group of distinct candidates behind one dead time gets its own lane-interleaved valve
 * pass. With paired != 0 (then P == m) the jobs are the m pairs (i, i) only and out is 2 x m: a
 * local search scores several points that each have their own structure in one call. Returns 0,
 * or -1 when memory runs out.
 */
KATTR int V(score_, SFX)(const double *x, int64_t n, const double *valves, int64_t m, const double *structs,
                         int64_t P, int paired, double ts, double ahp, const double *w, const double *yw,
                         const double *Qw, int64_t K, const double *Qty, double yyp, double *out, double gfix)
{
    const double *a1 = structs, *a2 = structs + P, *dd = structs + 2 * P, *integ = structs + 3 * P;
    if (m <= 0 || P <= 0 || (paired && P != m))
        return 0;
    if (!paired && m >= LANES && n > 0)
        return V(score_blocks_, SFX)(x, n, valves, m, structs, P, ts, ahp, w, yw, Qw, K, Qty, yyp, out, gfix);
    int64_t njobs = paired ? m : m * P;
    double *sse = out, *gain = out + njobs;
    /* each lane's valve output relative to its first sample, after dmax zeros (the input before
     * the record, seen through the longest dead time): the process loop reads it without a branch */
    int64_t dmax = 0;
    for (int64_t p = 0; p < P; p++)
        if ((int64_t)dd[p] > dmax)
            dmax = (int64_t)dd[p];
    int64_t nb = (n > 0 ? n : 1) + dmax;
    double *ubuf = (double *)scratch(SCRATCH_UBUF, sizeof(double) * (size_t)(LANES * nb));
    double szq[K > 0 ? K : 1];
    VT sq[K > 0 ? K : 1];
    if (ubuf == NULL)
        return -1;
    int64_t owner[LANES];       /* candidate whose valve output buffer b holds */
    for (int b = 0; b < LANES; b++) {
        owner[b] = -1;
        for (int64_t k = 0; k < dmax; k++)     /* the rest is written before it is read */
            ubuf[b * nb + k] = 0.0;
    }
    VT *il = NULL;              /* lane-interleaved valve rows of a direct group */
    /* a candidate's jobs in order of dead time: lanes that read the same row load it once */
    int64_t *order = NULL;
    if (!paired && P > 1) {
        order = (int64_t *)scratch(SCRATCH_ORDER, sizeof(int64_t) * (size_t)njobs);
        if (order == NULL)
            return -1;
        for (int64_t t = 0; t < njobs; t++)
            order[t] = ((t / P) * (dmax + 1) + (int64_t)dd[t % P]) * njobs + t;
        qsort(order, (size_t)njobs, sizeof(int64_t), cmp_i64);
        for (int64_t t = 0; t < njobs; t++)
            order[t] %= njobs;
    }
    int hp = ahp >= 0.0;
    for (int64_t t0 = 0; t0 < njobs; t0 += LANES) {
        int64_t ci[LANES], pi[LANES];
        const double *ug_ptr[LANES];
        for (int g = 0; g < LANES; g++) {
            int64_t t = t0 + g < njobs ? t0 + g : njobs - 1;     /* pad the last group */
            t = order ? order[t] : t;
            ci[g] = paired ? t : t / P;
            pi[g] = paired ? t : t % P;
        }
        /* a full group of distinct candidates behind one dead time (a local search's points): their
         * valves write lane-interleaved rows, and the process pass reads a vector per sample */
        int direct = t0 + LANES <= njobs;
        for (int g = 1; g < LANES && direct; g++) {
            direct = dd[pi[g]] == dd[pi[0]];
            for (int h = 0; h < g && direct; h++)
                direct = ci[h] != ci[g];
        }
        if (direct) {
            if (il == NULL) {
                il = (VT *)scratch(SCRATCH_ROWS, sizeof(VT) * (size_t)nb);
                if (il == NULL)
                    return -1;
                for (int64_t k = 0; k < dmax; k++)
                    il[k] = (VT){0.0};
            }
            plain_valves_t pv;
            VT A1, B1, A2, B2, I, N, sz, sy;
            for (int g = 0; g < LANES; g++) {
                plain_valve(&pv, g, valves, m, ci[g]);
                V(proc_lane_, SFX)(g, pi[g], a1, a2, integ, ts, &A1, &B1, &A2, &B2, &I, &N);
            }
            VT *u0 = il + dmax;
            V(valve_lanes_vec_, SFX)(x, n, pv.S, pv.J, pv.S, pv.J, ZEROS, ZEROS, NULL, NULL, pv.F, ZEROS, pv.y0,
                                     pv.xs0, ts, u0);
            VT first = u0[0];
            for (int64_t k = 0; k < n; k++)
                u0[k] -= first;
            const VT *in[1] = {u0 - (int64_t)dd[pi[0]]};
            V(score_groups_, SFX)(1, INPUT_VECTOR, n, in, NULL, &A1, &B1, &A2, &B2, &I, &N, hp, ahp, w, yw, Qw,
                                  K, &sz, &sy, sq);
            for (int g = 0; g < LANES; g++) {
                for (int64_t j = 0; j < K; j++)
                    szq[j] = sq[j][g];
                int64_t at = paired ? ci[g] : ci[g] * P + pi[g];
                finish_one(sz[g], sy[g], szq, Qty, K, yyp, gfix, &sse[at], &gain[at]);
            }
            continue;
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
            need_u[nneed] = ubuf + b * nb + dmax;
            nneed++;
            for (int h = g; h < LANES; h++)
                if (ci[h] == i)
                    buf_of[h] = b;
        }
        if (nneed > 0 && n > 0) {
            /* the new candidates' valves in one pass (spare lanes repeat the first) */
            plain_valves_t pv;
            double *o4[LANES];
            for (int g = 0; g < LANES; g++) {
                int h = g < nneed ? g : 0;
                plain_valve(&pv, g, valves, m, need_i[h]);
                o4[g] = need_u[h];
            }
            V(valve_lanes_, SFX)(x, n, pv.S, pv.J, pv.S, pv.J, ZEROS, ZEROS, NULL, NULL, pv.F, ZEROS, pv.y0,
                                 pv.xs0, ts, o4);
            for (int h = 0; h < nneed; h++) {
                double *row = need_u[h];
                double first = row[0];
                for (int64_t k = 0; k < n; k++)
                    row[k] -= first;
            }
        }
        VT A1, B1, A2, B2, I, N;
        for (int g = 0; g < LANES; g++) {
            int64_t p = pi[g];
            ug_ptr[g] = ubuf + buf_of[g] * nb + dmax - (int64_t)dd[p];
            V(proc_lane_, SFX)(g, p, a1, a2, integ, ts, &A1, &B1, &A2, &B2, &I, &N);
        }
        VT sz, sy;
        int same = 1;       /* every lane reads the same row (one valve, one dead time) */
        for (int g = 1; g < LANES; g++)
            same &= ug_ptr[g] == ug_ptr[0];
        if (same)
            V(score_groups_, SFX)(1, INPUT_BROADCAST, n, NULL, ug_ptr, &A1, &B1, &A2, &B2, &I, &N, hp, ahp, w, yw,
                                  Qw, K, &sz, &sy, sq);
        else
            V(score_groups_, SFX)(1, INPUT_GATHER, n, NULL, ug_ptr, &A1, &B1, &A2, &B2, &I, &N, hp, ahp, w, yw,
                                  Qw, K, &sz, &sy, sq);
        for (int g = 0; g < LANES && t0 + g < njobs; g++) {
            for (int64_t j = 0; j < K; j++)
                szq[j] = sq[j][g];
            int64_t at = paired ? ci[g] : ci[g] * P + pi[g];
            finish_one(sz[g], sy[g], szq, Qty, K, yyp, gfix, &sse[at], &gain[at]);
        }
    }
    return 0;
}

/*
 * The stem rows of the fused kernels, stored lane by lane: n + maxd vectors (maxd, the longest
 * dead time of the m candidates: each lane's first position before the record, then its n samples),
 * vector k holding every lane's sample. NULL when memory runs out.
 */
static VT *V(fused_rows_, SFX)(int64_t n, int64_t m, const int64_t *d, int64_t *maxd)
{
    *maxd = 0;
    for (int64_t i = 0; i < m; i++)
        if (d[i] > *maxd)
            *maxd = d[i];
    void *p = NULL;
    return posix_memalign(&p, sizeof(VT), sizeof(VT) * (size_t)(n + *maxd)) == 0 ? (VT *)p : NULL;
}

/*
 * The front both fused kernels share, for candidates i0 .. i0 + LANES - 1 (spare lanes repeat the
 * last): the lanes' stems in buf (their valves by valve_lanes, then each lane's valve
 * characteristic cc, preceded by maxd vectors of the first positions, what a dead time sees before
 * the record), where each lane's dead time starts reading (off: lane g's input at sample k is
 * buf[off[g] + k][g]), whether every lane reads from the same place (same: then buf[off[0] + k] is
 * the input vector), the first stem positions u0 and the process coefficients.
 */
static KATTR void V(fused_front_, SFX)(const double *x, int64_t n, int64_t m, int64_t i0, const double *S_up,
                                        const double *J_up, const double *S_dn, const double *J_dn,
                                        const double *dS, const double *dJ, const double *dt0,
                                        const double *dtw, const double *f0,
                                        const double *a_lag, const double *y0, const double *xs0,
                                        const double *cc, const double *a1, const double *a2, const int64_t *d,
                                        const uint8_t *integ, double ts_s, VT *buf, int64_t maxd, int64_t *off,
                                        int *same, VT *A1, VT *B1, VT *A2, VT *B2, VT *I, VT *N, VT *u0)
{
    double su[LANES], ju[LANES], sd[LANES], jd[LANES], ds[LANES], dj[LANES], f[LANES], a[LANES];
    double yv[LANES], sv[LANES], t0[LANES], tw[LANES];
    *same = 1;
    for (int g = 0; g < LANES; g++) {
        int64_t i = i0 + g < m ? i0 + g : m - 1;        /* spare lanes repeat the last candidate */
        su[g] = S_up[i]; ju[g] = J_up[i]; sd[g] = S_dn[i]; jd[g] = J_dn[i];
        ds[g] = dS[i]; dj[g] = dJ[i]; f[g] = f0[i]; a[g] = a_lag[i]; yv[g] = y0[i]; sv[g] = xs0[i];
        t0[g] = dt0 != NULL ? dt0[i] : 0.0;
        tw[g] = dtw != NULL ? dtw[i] : INFINITY;
        off[g] = maxd - d[i];
        *same &= off[g] == off[0];
        (*A1)[g] = a1[i];
        (*B1)[g] = 1.0 - a1[i];
        /* first order: z2 = 0 z2 + 1 z1, which is z1 exactly */
        (*A2)[g] = a2[i] >= 0.0 ? a2[i] : 0.0;
        (*B2)[g] = a2[i] >= 0.0 ? 1.0 - a2[i] : 1.0;
        (*I)[g] = integ[i] ? ts_s : 0.0;
        (*N)[g] = integ[i] ? 0.0 : 1.0;
    }
    VT *rows = buf + maxd;
    V(valve_lanes_vec_, SFX)(x, n, su, ju, sd, jd, ds, dj, t0, tw, f, a, yv, sv, ts_s, rows);
    for (int g = 0; g < LANES; g++) {
        int64_t i = i0 + g < m ? i0 + g : m - 1;
        characteristic_row((double *)rows + g, n, LANES, cc[i]);
    }
    *u0 = rows[0];
    for (int64_t k = 1; k <= maxd; k++)
        rows[-k] = *u0;
}

/*
 * fused_sse for this instruction set: LANES candidates at a time, their valves (valve_lanes), the
 * characteristic on each stem row, then the process and the candidate's normal-equation sums in
 * the same lanes; fused_solve finishes each candidate. Each lane performs exactly the operations
 * of a one-candidate loop over the samples, so the result does not depend on the width.
 */
KATTR int V(fused_, SFX)(const double *x, int64_t n, int64_t m, const double *S_up, const double *J_up,
                         const double *S_dn, const double *J_dn, const double *dS, const double *dJ,
                         const double *dt0, const double *dtw, const double *f0, const double *a_lag,
                         const double *y0, const double *xs0,
                         const double *cc, const double *a1, const double *a2, const int64_t *d,
                         const uint8_t *integ, double ts_s, const double *E, int64_t q, const double *y,
                         const double *w, double sgn, double *out)
{
    if (2 + q > FUSED_MAXP)
        return -1;
    if (m <= 0 || n <= 0)
        return 0;
    int64_t maxd;
    VT *buf = V(fused_rows_, SFX)(n, m, d, &maxd);
    if (buf == NULL)
        return -1;
    fused_fixed_t fx;
    fused_fixed(n, E, q, y, w, &fx);
    VT szE[FUSED_MAXP], sEz[FUSED_MAXP];
    for (int64_t i0 = 0; i0 < m; i0 += LANES) {
        int64_t off[LANES];
        int same;
        VT A1, B1, A2, B2, I, N, u0;
        V(fused_front_, SFX)(x, n, m, i0, S_up, J_up, S_dn, J_dn, dS, dJ, dt0, dtw, f0, a_lag, y0, xs0, cc, a1, a2,
                             d, integ,
                             ts_s, buf, maxd, off, &same, &A1, &B1, &A2, &B2, &I, &N, &u0);
        const VT *in = buf + off[0];
        VT z1 = u0, z2 = u0, ac = {0.0}, szz = {0.0}, sz = {0.0}, szy = {0.0};
        for (int64_t j = 0; j < q; j++) {
            szE[j] = (VT){0.0};
            sEz[j] = (VT){0.0};
        }
        for (int64_t k = 0; k < n; k++) {
            VT ud;
            if (same)
                ud = in[k];
            else
                for (int g = 0; g < LANES; g++)
                    ud[g] = buf[off[g] + k][g];
            z1 = A1 * z1 + B1 * ud;
            z2 = A2 * z2 + B2 * z1;
            ac += I * z2;
            VT v = N * z2 + ac;
            double wk = w[k];
            if (wk == 0.0)
                continue;
            double yk = y[k];
            VT wz = wk * v;
            szz += wz * v;
            sz += wz;
            szy += wz * yk;
            for (int64_t j = 0; j < q; j++) {
                double ej = E[k * q + j];
                szE[j] += wz * ej;
                sEz[j] += (wk * ej) * v;
            }
        }
        for (int g = 0; g < LANES && i0 + g < m; g++) {
            double se[FUSED_MAXP], es[FUSED_MAXP];
            for (int64_t j = 0; j < q; j++) {
                se[j] = szE[j][g];
                es[j] = sEz[j][g];
            }
            out[i0 + g] = fused_solve(szz[g], sz[g], szy[g], se, es, &fx, q, sgn);
        }
    }
    free(buf);
    return 0;
}

/*
 * fused_sse with a sinusoidal load of its own per candidate: the extra columns are [t] (with_t: an
 * integrating process) and sin(w_i t), cos(w_i t) with t = k ts and w_i = wload[i] (rad/s), so the
 * sums of 1, E and y are the candidate's own too. The sine and cosine are computed with libm at
 * every `LOAD_ANCHOR`-th sample and rotated by w_i ts in between (relative error about 1e-14).
 */
KATTR int V(fused_load_, SFX)(const double *x, int64_t n, int64_t m, const double *S_up, const double *J_up,
                              const double *S_dn, const double *J_dn, const double *dS, const double *dJ,
                              const double *dt0, const double *dtw, const double *f0, const double *a_lag,
                              const double *y0, const double *xs0, const double *cc, const double *a1,
                              const double *a2, const int64_t *d,
                              const uint8_t *integ, double ts_s, const double *wload, int with_t,
                              const double *y, const double *w, double sgn, double *out)
{
    const int64_t q = with_t ? 3 : 2;
    if (m <= 0 || n <= 0)
        return 0;
    int64_t maxd;
    VT *buf = V(fused_rows_, SFX)(n, m, d, &maxd);
    if (buf == NULL)
        return -1;
    fused_fixed_t base;
    fused_fixed(n, NULL, 0, y, w, &base);
    for (int64_t i0 = 0; i0 < m; i0 += LANES) {
        double wl[LANES];
        int64_t off[LANES];
        int same;
        VT A1, B1, A2, B2, I, N, u0, rs, rc;
        V(fused_front_, SFX)(x, n, m, i0, S_up, J_up, S_dn, J_dn, dS, dJ, dt0, dtw, f0, a_lag, y0, xs0, cc, a1, a2,
                             d, integ,
                             ts_s, buf, maxd, off, &same, &A1, &B1, &A2, &B2, &I, &N, &u0);
        const VT *in = buf + off[0];
        for (int g = 0; g < LANES; g++) {
            wl[g] = wload[i0 + g < m ? i0 + g : m - 1];
            rs[g] = sin(wl[g] * ts_s);
            rc[g] = cos(wl[g] * ts_s);
        }
        VT zero = {0.0};
        VT z1 = u0, z2 = u0, ac = zero, szz = zero, sz = zero, szy = zero, sn = zero, cs = zero;
        VT szE[3], sEz[3], sE[3], sEy[3], sEE[9];
        for (int j = 0; j < 3; j++) {
            szE[j] = zero; sEz[j] = zero; sE[j] = zero; sEy[j] = zero;
        }
        for (int j = 0; j < 9; j++)
            sEE[j] = zero;
        for (int64_t k = 0; k < n; k++) {
            double tk = (double)k * ts_s;
            if (k % LOAD_ANCHOR == 0) {
                for (int g = 0; g < LANES; g++) {
                    double ang = wl[g] * tk;
                    sn[g] = sin(ang);
                    cs[g] = cos(ang);
                }
            }
            VT ud;
            if (same)
                ud = in[k];
            else
                for (int g = 0; g < LANES; g++)
                    ud[g] = buf[off[g] + k][g];
            z1 = A1 * z1 + B1 * ud;
            z2 = A2 * z2 + B2 * z1;
            ac += I * z2;
            VT v = N * z2 + ac;
            double wk = w[k];
            if (wk != 0.0) {
                double yk = y[k];
                VT e[3];
                int j0 = 0;
                if (with_t)
                    e[j0++] = zero + tk;
                e[j0] = sn;
                e[j0 + 1] = cs;
                VT wz = wk * v;
                szz += wz * v;
                sz += wz;
                szy += wz * yk;
                for (int j = 0; j < q; j++) {
                    VT we = wk * e[j];
                    szE[j] += wz * e[j];
                    sEz[j] += we * v;
                    sE[j] += we;
                    sEy[j] += we * yk;
                    for (int l = 0; l < q; l++)
                        sEE[j * q + l] += we * e[l];
                }
            }
            VT sn1 = sn * rc + cs * rs;
            cs = cs * rc - sn * rs;
            sn = sn1;
        }
        for (int g = 0; g < LANES && i0 + g < m; g++) {
            fused_fixed_t fx = base;
            double se[FUSED_MAXP], es[FUSED_MAXP];
            for (int j = 0; j < q; j++) {
                se[j] = szE[j][g];
                es[j] = sEz[j][g];
                fx.sE[j] = sE[j][g];
                fx.sEy[j] = sEy[j][g];
                for (int l = 0; l < q; l++)
                    fx.sEE[j * q + l] = sEE[j * q + l][g];
            }
            out[i0 + g] = fused_solve(szz[g], sz[g], szy[g], se, es, &fx, q, sgn);
        }
    }
    free(buf);
    return 0;
}

#undef VT
#undef MT
#undef V
#undef V_
