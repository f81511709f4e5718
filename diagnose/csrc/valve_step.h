/*
 * The valve step: one sample of the stiction model, the only place it is written.
 *
 * The two-parameter model of Choudhury, Thornhill & Shah (2005) in its revised form (equal to Kano
 * et al. 2004 sample for sample; docs/model.md), with separate (S, J) for the two directions of
 * motion (the augmented valve of `stiction explain`; equal values give the plain model):
 *
 *     x = clip(x_k, 0, 100); v = x - x_prev
 *     if moving and (v == 0 or sign(v) != sign(v_prev)): stuck; x_ss = x_prev   (only a moving
 *                                                          valve stops: noise cannot re-capture)
 *     if stuck and -f (x - x_ss) > S_new:  f = -f; moving        (reversal must beat S of the new
 *                                                                direction)
 *     elif stuck and f (x - x_ss) > J_f:    moving                (restart must beat J)
 *     if moving: y = clip(x - f (S_f - J_f) / 2)  else y = y_prev
 *
 * The friction may drift or step in time: VFRICTION below is the one schedule every valve path runs.
 *
 * Template: included with VSTEP and VFRICTION (function names), VT (vector of doubles), MT (mask of
 * the same width, from comparisons of VT) and VATTR (function attributes: the ISA) defined. The step is
 * branch free per lane so that any number of candidate valves driven by the same input run in one
 * vector (lanes); a one-lane vector is the scalar valve. Every lane performs the same IEEE
 * operations in the same order at any width, so results do not depend on the CPU.
 *
 * State per lane: stuck (mask), xss (stuck point), f (direction of the last motion, +-1), yp (stem).
 * Shared by all lanes: the input xk, the previous input xp, and `stop` (the input stopped or
 * reversed: a moving valve stops).
 */
static inline __attribute__((always_inline)) VATTR
void VSTEP(double xk, double xp, int stop, MT *stuck, VT *xss, VT *f, VT *yp,
           VT su, VT ju, VT sd, VT jd)
{
    const VT zero = (VT){0.0} * 0.0;
    VT xkv = zero + xk;
    if (stop) {
        VT xpv = zero + xp;
        *xss = (VT)(((MT)*xss & *stuck) | ((MT)xpv & ~*stuck));
        *stuck = *stuck | ~*stuck;
    }
    VT fv = *f;
    VT d = xkv - *xss;
    MT fpos = fv > zero;
    /* reversal into -f must beat S of that direction; a restart in direction f must beat J of f */
    VT s_new = (VT)(((MT)sd & fpos) | ((MT)su & ~fpos));
    VT j_same = (VT)(((MT)ju & fpos) | ((MT)jd & ~fpos));
    MT rev = *stuck & ((-fv) * d > s_new);
    MT fwd = *stuck & ~rev & (fv * d > j_same);
    MT move = ~*stuck | rev | fwd;
    fv = (VT)(((MT)(-fv) & rev) | ((MT)fv & ~rev));
    *stuck = *stuck & ~(rev | fwd);
    fpos = fv > zero;
    VT half = (VT)(((MT)(su - ju) & fpos) | ((MT)(sd - jd) & ~fpos)) / 2.0;
    VT yn = xkv - fv * half;
    /* clip to the valve's travel, as max(.., 0) then min(.., 100) */
    VT lo = zero, hi = zero + 100.0;
    yn = (VT)(((MT)lo & (lo > yn)) | ((MT)yn & ~(lo > yn)));
    yn = (VT)(((MT)hi & (hi < yn)) | ((MT)yn & ~(hi < yn)));
    *yp = (VT)(((MT)yn & move) | ((MT)*yp & ~move));
    *f = fv;
}

/*
 * S and J of both directions t_s seconds after the first sample: each drifts at ds (S) or dj (J)
 * per second from t0 for tw seconds (one sample period: a step) and is clipped at 0. A rate of 0
 * leaves its value as it is at any time, also for t_s or tw infinite (no 0 * inf).
 */
static inline __attribute__((always_inline)) VATTR
void VFRICTION(VT t_s, VT t0, VT tw, VT su0, VT ju0, VT sd0, VT jd0, VT ds, VT dj,
               VT *su, VT *ju, VT *sd, VT *jd)
{
    const VT zero = (VT){0.0} * 0.0;
    VT t = t_s - t0;
    t = (VT)(((MT)zero & (zero > t)) | ((MT)t & ~(zero > t)));
    t = (VT)(((MT)tw & (tw < t)) | ((MT)t & ~(tw < t)));
    VT dsv = (VT)((MT)(ds * t) & (ds != zero));
    VT djv = (VT)((MT)(dj * t) & (dj != zero));
    VT v[4] = {su0 + dsv, ju0 + djv, sd0 + dsv, jd0 + djv};
    for (int i = 0; i < 4; i++)
        v[i] = (VT)(((MT)zero & (zero > v[i])) | ((MT)v[i] & ~(zero > v[i])));
    *su = v[0];
    *ju = v[1];
    *sd = v[2];
    *jd = v[3];
}
