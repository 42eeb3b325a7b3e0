/* solver.cl - the update steps of the compensation solve (DESIGN.md §3) and the reductions of
 * its exact line search; NumPy twin: rtdefocus/reference/ops.py (NumpyOps).
 *
 *   min_P d(F P, I)  subject to 0 <= P <= 1,   grad d = 2 F^T q,  q = Q (F P - I)  (metric.cl)
 *
 *   pg_direction   s = -g on the free set (0 where P sits at a bound and -g points outward);
 *                  s = -pc g with PRECOND
 *   pg_step        P <- clamp(P + t s, 0, 1); delta = the step actually taken
 *   axpy           x <- x + a y   (moving back along the chord of a clamped step)
 *   fista_step     P_out = clamp(y - step (G + beta (G - G_prev)), 0, 1),  y = P + beta (P - P_prev)
 *                  (the gradient at y by linearity from the gradients at P_k and P_k-1)
 *   fista_set_d, fista_decide, fista_undo
 *                  FISTA's restart test on the device (no read-back per iteration; see there)
 *   reduce_partials  second stage of every reduction (first stage: in these kernels / metric.cl)
 *   decode_lut     uint8 (H, W, 3) codes -> planar linear light through the response LUT (+ headroom)
 *   encode_lut     planar linear P -> uint8 (H, W, 3) codes through the inverse response
 *
 * Layout: images are planar float32 (3, H, W) treated as flat arrays of n = 3 H W elements;
 * g / G hold F^T q (the factor 2 of grad d is folded into t and step by the host).
 * Element kernels: each work-item takes ITEMS chunks of VEC consecutive elements (float16 on a
 * CPU, scalars on a GPU), chunk j of group b being b*WG*ITEMS + j*WG + local id (so neighbouring
 * work-items touch neighbouring memory); global size ceil(n / (VEC*ITEMS*WG)) * WG, local WG.
 * partials: float32 (NQ, n_groups) as partials[k * n_groups + group].
 * decode_lut: one work-item per pixel; encode_lut: 16 pixels per work-item (see there).
 *
 * PRECOND (0/1, default 0; surface="flatten", DESIGN.md §3): pg_direction and fista_step scale
 * the gradient by a per-element diagonal preconditioner pc (float32 (3, H, W),
 * rtdefocus.reference.ops.scale_preconditioner): s = -pc g, and pg_direction's partial becomes
 * sum pc g^2 (= -<g, s>, what the exact line search needs); P_out = clamp(y - step pc g_y).
 * Without it `pc` is never read (any buffer will do) and the arithmetic is unchanged.
 *
 * Constants (-D): WG (a power of two within the device's work-group limit), ITEMS, VEC (16 or 1);
 * PRECOND; ENC_T, ENC_STEPS (encode_lut's table size and correction steps).
 */
#include "common.h"

#if !defined(WG) || !defined(ITEMS) || !defined(VEC)
#error "solver.cl needs -D WG, ITEMS and VEC"
#endif

#ifndef PRECOND
#define PRECOND 0
#endif

#if VEC == 16
typedef float16 vecf;
typedef float16 __attribute__((aligned(4))) float16_u;   /* one unaligned vector move */

inline vecf vld(__global const float *restrict p, const size_t i, const size_t n)
{
    if (i + 16 <= n) return *(__global const float16_u *)(p + i);
    float tmp[16];
    for (int j = 0; j < 16; ++j) tmp[j] = i + j < n ? p[i + j] : 0.0f;
    return vload16(0, tmp);
}

inline void vst(__global float *restrict p, const size_t i, const size_t n, const vecf v)
{
    if (i + 16 <= n) { *(__global float16_u *)(p + i) = v; return; }
    float tmp[16];
    vstore16(v, 0, tmp);
    for (int j = 0; j < 16 && i + j < n; ++j) p[i + j] = tmp[j];
}

inline float vsum(const vecf v) { return hsum16(v); }
#elif VEC == 1
typedef float vecf;
inline vecf vld(__global const float *restrict p, const size_t i, const size_t n) { return i < n ? p[i] : 0.0f; }
inline void vst(__global float *restrict p, const size_t i, const size_t n, const vecf v) { if (i < n) p[i] = v; }
inline float vsum(const vecf v) { return v; }
#else
#error "VEC must be 16 or 1"
#endif

/* The FISTA state vector's slots (fista_decide). */
#define S_D 0
#define S_THETA 1
#define S_BETA 2
#define S_STEP 3
#define S_ACCEPT 4
#define S_RESTARTS 5
#define S_LOG 8

/* Element index of chunk j of this work-item. */
#define CHUNK(j) (((size_t)get_group_id(0) * WG * ITEMS + (size_t)(j) * WG + get_local_id(0)) * VEC)

/* s = -g (PRECOND: -pc g) where P may move that way, else 0.  partials[0] = -<g, s>
 * (sum s^2 without PRECOND). */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void pg_direction(__global const float *restrict P, __global const float *restrict g,
                  __global float *restrict s, __global const float *restrict pc,
                  __global float *restrict partials, const int n)
{
    __local float4 scratch[WG];
    vecf acc = (vecf)(0.0f);
    for (int j = 0; j < ITEMS; ++j) {
        const size_t i = CHUNK(j);
        if (i >= (size_t)n) break;
        const vecf p = vld(P, i, n), gi = vld(g, i, n);
#if PRECOND
        const vecf si = select(-(vld(pc, i, n) * gi), (vecf)(0.0f),
                               (p <= 0.0f && gi > 0.0f) || (p >= 1.0f && gi < 0.0f));
        vst(s, i, n, si);
        acc -= gi * si;
#else
        const vecf si = select(-gi, (vecf)(0.0f), (p <= 0.0f && gi > 0.0f) || (p >= 1.0f && gi < 0.0f));
        vst(s, i, n, si);
        acc += si * si;
#endif
    }
    store_partials(partials, wg_sum4(scratch, (float4)(vsum(acc), 0.0f, 0.0f, 0.0f), WG), 1);
}

/* P <- clamp(P + t s, 0, 1); delta = new P - old P.
 * partials: [0] sum delta^2, [1] sum P_new^2, [2] number of elements the clamp changed. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void pg_step(__global float *restrict P, __global const float *restrict s, const float t,
             __global float *restrict delta, __global float *restrict partials, const int n)
{
    __local float4 scratch[WG];
    vecf a0 = (vecf)(0.0f), a1 = a0, a2 = a0;
    for (int j = 0; j < ITEMS; ++j) {
        const size_t i = CHUNK(j);
        if (i >= (size_t)n) break;
        const vecf p = vld(P, i, n), moved = p + t * vld(s, i, n);
        const vecf pn = clamp(moved, 0.0f, 1.0f);
        const vecf d = pn - p;
        vst(P, i, n, pn);
        vst(delta, i, n, d);
        a0 += d * d;
        a1 += pn * pn;
        a2 += select((vecf)(0.0f), (vecf)(1.0f), pn != moved);
    }
    store_partials(partials, wg_sum4(scratch, (float4)(vsum(a0), vsum(a1), vsum(a2), 0.0f), WG), 3);
}

/* x <- x + a y. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void axpy(__global float *restrict x, __global const float *restrict y, const float a, const int n)
{
    for (int j = 0; j < ITEMS; ++j) {
        const size_t i = CHUNK(j);
        if (i >= (size_t)n) break;
        vst(x, i, n, vld(x, i, n) + a * vld(y, i, n));
    }
}

/* P_out = clamp(y - step g_y, 0, 1) (PRECOND: step pc g_y) with y = P + beta (P - P_prev), g_y = G + beta (G - G_prev)
 * (P_prev and G_prev are not read when beta == 0; P_out distinct from the inputs); with
 * from_state != 0, beta and step are read from the device state (fista_decide) instead.
 * partials: [0] sum (P_out - P)^2, [1] sum P_out^2. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void fista_step(__global const float *restrict P, __global const float *restrict P_prev,
                __global const float *restrict G, __global const float *restrict G_prev,
                float beta, float step, __global const float *restrict pc,
                __global float *restrict P_out, __global float *restrict partials, const int n,
                __global const float *restrict state, const int from_state)
{
    if (from_state) {
        beta = state[S_BETA];
        step = state[S_STEP];
    }
    __local float4 scratch[WG];
    vecf a0 = (vecf)(0.0f), a1 = a0;
    for (int j = 0; j < ITEMS; ++j) {
        const size_t i = CHUNK(j);
        if (i >= (size_t)n) break;
        const vecf p = vld(P, i, n), g = vld(G, i, n);
        vecf y = p, gy = g;
        if (beta != 0.0f) {
            y += beta * (p - vld(P_prev, i, n));
            gy += beta * (g - vld(G_prev, i, n));
        }
#if PRECOND
        gy *= vld(pc, i, n);
#endif
        const vecf pn = clamp(y - step * gy, 0.0f, 1.0f);
        vst(P_out, i, n, pn);
        const vecf d = pn - p;
        a0 += d * d;
        a1 += pn * pn;
    }
    store_partials(partials, wg_sum4(scratch, (float4)(vsum(a0), vsum(a1), 0.0f, 0.0f), WG), 2);
}

/* FISTA's function-value restart on the device, so that an iteration needs no read-back
 * (rtdefocus.compensate.solvers; NumPy twin NumpyOps.fista_decide). state: float32
 * [S_D, S_THETA, S_BETA, S_STEP, S_ACCEPT, S_RESTARTS, -, -, log...]: the distance at the
 * current iterate, the momentum, the step 2/L, whether the last step was accepted, the count of
 * rejected steps, and log[k] the distance after step k (log[0]: at the start).
 * fista_set_d: state[S_D] = log[0] = the sum of the metric's partials (one work-group).
 * fista_decide: d_new = that sum (the same order as reduce_partials); a step that increases d is
 * rejected (S_ACCEPT = 0; theta = 1, beta = 0; if beta was already 0, L doubles: step halves),
 * else d = d_new and theta' = (1 + sqrt(1 + 4 theta^2)) / 2, beta = (theta - 1) / theta';
 * log[1 + k] = d. fista_undo: where the step was rejected, copy P -> P_out and q -> q_out, so
 * that the host rotates its buffers as if every step were accepted. */
inline float sum_partials(__local float4 *scratch, __global const float *restrict partials,
                          const int n_groups)
{
    float acc = 0.0f;
    for (int g = get_local_id(0); g < n_groups; g += WG) acc += partials[g];
    return wg_sum4(scratch, (float4)(acc, 0.0f, 0.0f, 0.0f), WG).x;
}

__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void fista_set_d(__global const float *restrict partials, const int n_groups,
                 __global float *restrict state)
{
    __local float4 scratch[WG];
    const float d = sum_partials(scratch, partials, n_groups);
    if (get_local_id(0) == 0) state[S_D] = state[S_LOG] = d;
}

__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void fista_decide(__global const float *restrict partials, const int n_groups,
                  __global float *restrict state, const int k)
{
    __local float4 scratch[WG];
    const float d_new = sum_partials(scratch, partials, n_groups);
    if (get_local_id(0) != 0) return;
    const float d = state[S_D], theta = state[S_THETA], beta = state[S_BETA];
    if (d_new > d) {
        state[S_ACCEPT] = 0.0f;
        state[S_RESTARTS] += 1.0f;
        if (beta == 0.0f) state[S_STEP] *= 0.5f;
        state[S_THETA] = 1.0f;
        state[S_BETA] = 0.0f;
        state[S_LOG + 1 + k] = d;
    } else {
        const float theta_next = (1.0f + sqrt(1.0f + 4.0f * theta * theta)) / 2.0f;
        state[S_ACCEPT] = 1.0f;
        state[S_D] = d_new;
        state[S_BETA] = (theta - 1.0f) / theta_next;
        state[S_THETA] = theta_next;
        state[S_LOG + 1 + k] = d_new;
    }
}

/* fista_undo runs after every step but copies only after a rejected one (rare): it is launched
 * on a few work-groups that stride over the arrays, so that an accepted step costs a launch, not
 * one early exit per chunk (~2800 groups at 800x600: ~3 ms on 2 PoCL cores). */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void fista_undo(__global const float *restrict state, __global const float *restrict P,
                __global float *restrict P_out, __global const float *restrict q,
                __global float *restrict q_out, const int n)
{
    if (state[S_ACCEPT] != 0.0f) return;
    const size_t stride = (size_t)get_global_size(0) * VEC;
    for (size_t i = (size_t)get_global_id(0) * VEC; i < (size_t)n; i += stride) {
        vst(P_out, i, n, vld(P, i, n));
        vst(q_out, i, n, vld(q, i, n));
    }
}

/* dst = clamp(src, 0, 1). */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void clamp_copy(__global const float *restrict src, __global float *restrict dst, const int n)
{
    for (int j = 0; j < ITEMS; ++j) {
        const size_t i = CHUNK(j);
        if (i >= (size_t)n) break;
        vst(dst, i, n, clamp(vld(src, i, n), 0.0f, 1.0f));
    }
}

/* Second stage: out[k] = sum_g partials[k * n_groups + g]; one work-group of WG items per k.
 * Global size (nq * WG), local size WG. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void reduce_partials(__global const float *restrict partials, const int n_groups,
                     __global float *restrict out)
{
    __local float4 scratch[WG];
    const int k = get_group_id(0);
    float acc = 0.0f;
    for (int g = get_local_id(0); g < n_groups; g += WG) acc += partials[k * n_groups + g];
    const float4 total = wg_sum4(scratch, (float4)(acc, 0.0f, 0.0f, 0.0f), WG);
    if (get_local_id(0) == 0) out[k] = total.x;
}

/* dst[c, y, x] = lo + scale * lut[c, src[y, x, c]]: decode the warped frame to linear light and
 * map it into the headroom [lo, lo + scale].  src uint8 (H, W, 3), lut float32 (3, 256),
 * dst float32 (3, H, W); npix = H W. Each work-item takes VEC consecutive pixels (global size
 * ceil(ceil(npix / VEC) / WG) * WG, like carry): a pixel per work-item made 60000 groups of 8
 * on a CPU device, 1.2 ms at 800x600 on PoCL, of which the scheduling was most. */
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void decode_lut(__global const uchar *restrict src, __global const float *restrict lut,
                const float lo, const float scale, __global float *restrict dst, const int npix)
{
    const int i0 = get_global_id(0) * VEC;
    const int i1 = min(i0 + VEC, npix);
    for (int i = i0; i < i1; ++i)
        for (int c = 0; c < 3; ++c)
            dst[(size_t)c * npix + i] = lo + scale * lut[c * 256 + src[3 * i + c]];
}

/* dst[y, x, c] = the code whose response is nearest P[c, y, x] under piecewise-linear
 * interpolation of the strictly increasing response (3, 256): the number of code midpoints
 * mid[c, v] = (lut[c, v] + lut[c, v + 1]) / 2 that are <= P (mid[c, 255] = +inf).
 * The count starts from tab[c, b], its value at the start of P's bin b = floor(P * ENC_T) (host
 * table), and is finished by ENC_STEPS comparisons; exact when no bin holds more midpoints
 * (the host checks; the NumPy twin does the very same steps). A binary search with a
 * data-dependent loop ran ~25x slower on PoCL. Each work-item encodes 16 pixels and writes their
 * 48 interleaved bytes as three 16-byte vectors.
 * P float32 (3, H, W), mid float32 (3, 256), tab uint8 (3, ENC_T), dst uint8 (H, W, 3);
 * npix = H W; global size ceil(ceil(npix / 16) / WG) * WG. */
#ifndef ENC_T
#define ENC_T 16384
#endif
#ifndef ENC_STEPS
#define ENC_STEPS 4
#endif
__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void encode_lut(__global const float *restrict P, __global const float *restrict mid,
                __global const uchar *restrict tab, __global uchar *restrict dst, const int npix)
{
    const int i0 = get_global_id(0) * 16;
    if (i0 >= npix) return;
    uchar out[48];
    for (int c = 0; c < 3; ++c) {
        __global const float *m = mid + c * 256;
        __global const uchar *tb = tab + c * ENC_T;
        for (int j = 0; j < 16; ++j) {
            const float p = i0 + j < npix ? P[(size_t)c * npix + i0 + j] : 0.0f;
            int code = tb[clamp((int)(p * (float)ENC_T), 0, ENC_T - 1)];
            for (int k = 0; k < ENC_STEPS; ++k) code += p >= m[code] ? 1 : 0;
            out[3 * j + c] = (uchar)code;
        }
    }
    if (i0 + 16 <= npix) {
        for (int k = 0; k < 3; ++k) vstore16(vload16(k, out), 0, dst + 3 * (size_t)i0 + 16 * k);
    } else {
        for (int k = 0; k < 3 * (npix - i0); ++k) dst[3 * (size_t)i0 + k] = out[k];
    }
}

/* dst = base_new + B(src - base_prev) where valid, else fallback; clamped to [0, 1] with CARRY_CLAMP.
 * B samples the previous frame bilinearly at map[y, x] = (x', y'), taps outside the frame count
 * as 0; CARRY_IDENTITY: no resampling (B = the field itself); without CARRY_BASE the bases are
 * 0 (not read). The warm start of a video moves the previous correction, FISTA's previous
 * iterate and its gradient along the motion without a trip to the host. NumPy twin:
 * rtdefocus.reference.ops.carry_field. src, base_prev, base_new, fallback, dst float32
 * (3, H, W); map float2 (H, W); valid uchar (H, W); each work-item takes VEC consecutive pixels
 * (global size ceil(ceil(H W / VEC) / WG) * WG): one pixel per work-item made ~60000 groups of
 * 8 on a CPU device, whose scheduling cost ~20 ms a call on PoCL; a loop of 16 pixels ~2 ms.
 * dst may be base_new or fallback, never src or base_prev. CARRY_TWO: also dst2 = the same carry
 * of src2 (FISTA's previous iterate beside P), by the same work-item right after the first, so
 * that the map, mask, bases and fallback it reads again are still in its cache (two fields in
 * one call: 5.3 ms at 800x600 on 2 PoCL cores, where two calls took 6.1). */
#define CARRY_BASE 1
#define CARRY_CLAMP 2
#define CARRY_IDENTITY 4
#define CARRY_TWO 8
inline void carry_pixel(__global const float *restrict src, __global const float *restrict base_prev,
                        __global const float *base_new, __global const float *fallback,
                        __global const float2 *restrict map, __global const uchar *restrict valid,
                        __global float *dst, const int flags, const int H, const int W, const int i)
{
    const int npix = H * W;
    const bool base = flags & CARRY_BASE;
    float out[3];
    if (!valid[i]) {
        for (int c = 0; c < 3; ++c) out[c] = fallback[(size_t)c * npix + i];
    } else if (flags & CARRY_IDENTITY) {
        for (int c = 0; c < 3; ++c) {
            const size_t j = (size_t)c * npix + i;
            out[c] = base ? base_new[j] + (src[j] - base_prev[j]) : src[j];
        }
    } else {
        /* branch-free bilinear: taps outside the frame get weight 0 (read at a clamped
         * index), the same sums in the same order as skipping them (x + 0 = x) */
        const float2 m = clamp(map[i], -2.0f, (float2)((float)W + 1.0f, (float)H + 1.0f));
        const float fx0 = floor(m.x), fy0 = floor(m.y);
        const float fx = m.x - fx0, fy = m.y - fy0;
        const int x0 = (int)fx0, y0 = (int)fy0;
        const float wx0 = (x0 >= 0 && x0 < W) ? 1.0f - fx : 0.0f;
        const float wx1 = (x0 + 1 >= 0 && x0 + 1 < W) ? fx : 0.0f;
        const float wy0 = (y0 >= 0 && y0 < H) ? 1.0f - fy : 0.0f;
        const float wy1 = (y0 + 1 >= 0 && y0 + 1 < H) ? fy : 0.0f;
        const int xa = clamp(x0, 0, W - 1), xb = clamp(x0 + 1, 0, W - 1);
        const int ra = clamp(y0, 0, H - 1) * W, rb = clamp(y0 + 1, 0, H - 1) * W;
        const float w00 = wy0 * wx0, w01 = wy0 * wx1, w10 = wy1 * wx0, w11 = wy1 * wx1;
        for (int c = 0; c < 3; ++c) {
            __global const float *s = src + (size_t)c * npix, *b = base_prev + (size_t)c * npix;
            float v00 = s[ra + xa], v01 = s[ra + xb], v10 = s[rb + xa], v11 = s[rb + xb];
            if (base) {
                v00 -= b[ra + xa]; v01 -= b[ra + xb]; v10 -= b[rb + xa]; v11 -= b[rb + xb];
            }
            out[c] = 0.0f;
            out[c] += w00 * v00;
            out[c] += w01 * v01;
            out[c] += w10 * v10;
            out[c] += w11 * v11;
        }
        if (base)
            for (int c = 0; c < 3; ++c) out[c] += base_new[(size_t)c * npix + i];
    }
    for (int c = 0; c < 3; ++c)
        dst[(size_t)c * npix + i] = (flags & CARRY_CLAMP) ? clamp(out[c], 0.0f, 1.0f) : out[c];
}

#if VEC == 16
/* 16 lanes of p[idx[k]] (a CPU has no cheaper gather; the loop is what LLVM vectorises). */
inline float16 gather16(__global const float *restrict p, const int16 i)
{
    return (float16)(p[i.s0], p[i.s1], p[i.s2], p[i.s3], p[i.s4], p[i.s5], p[i.s6], p[i.s7],
                     p[i.s8], p[i.s9], p[i.sa], p[i.sb], p[i.sc], p[i.sd], p[i.se], p[i.sf]);
}

inline int hmin16(const int16 v)
{
    const int8 a = min(v.lo, v.hi);
    const int4 b = min(a.lo, a.hi);
    const int2 c = min(b.lo, b.hi);
    return min(c.x, c.y);
}

inline int hmax16(const int16 v)
{
    const int8 a = max(v.lo, v.hi);
    const int4 b = max(a.lo, a.hi);
    const int2 c = max(b.lo, b.hi);
    return max(c.x, c.y);
}

/* The left and right taps of 16 lanes whose row starts at p + o0 (lanes with hi_row: p + o1),
 * lane k reading column k (hi_col: k + 1) and the next one. */
inline void row_taps(__global const float *restrict p, const int o0, const int o1,
                     const int16 hi_col, const int16 hi_row, float16 *left, float16 *right)
{
    const float16 a0 = vload16(0, p + o0), a1 = vload16(0, p + o0 + 1), a2 = vload16(0, p + o0 + 2);
    const float16 b0 = vload16(0, p + o1), b1 = vload16(0, p + o1 + 1), b2 = vload16(0, p + o1 + 2);
    const float16 l0 = select(a0, a1, hi_col), r0 = select(a1, a2, hi_col);
    const float16 l1 = select(b0, b1, hi_col), r1 = select(b1, b2, hi_col);
    *left = select(l0, l1, hi_row);
    *right = select(r0, r1, hi_row);
}

/* The CPU shape: 16 consecutive pixels per work-item as float16 vectors (scalar per-pixel code
 * ran ~4x slower than cv2.remap on PoCL); the same arithmetic, lane by lane, as carry_pixel. */
inline void carry16(__global const float *restrict src, __global const float *restrict base_prev,
                    __global const float *base_new, __global const float *fallback,
                    __global const float2 *restrict map, __global const uchar *restrict valid,
                    __global float *dst, const int flags, const int H, const int W, const int i0)
{
    const int npix = H * W;
    const bool base = flags & CARRY_BASE;
    const int16 ok = convert_int16(vload16(0, valid + i0)) != 0;
    float16 out[3];
    if (flags & CARRY_IDENTITY) {
        for (int c = 0; c < 3; ++c) {
            const size_t j = (size_t)c * npix + i0;
            const float16 sv = vload16(0, src + j);
            out[c] = base ? vload16(0, base_new + j) + (sv - vload16(0, base_prev + j)) : sv;
        }
    } else {
        __global const float *mp = (__global const float *)(map + i0);
        const float16 lo = vload16(0, mp), hi = vload16(1, mp);
        const float16 mx = clamp((float16)(lo.even, hi.even), -2.0f, (float)W + 1.0f);
        const float16 my = clamp((float16)(lo.odd, hi.odd), -2.0f, (float)H + 1.0f);
        const float16 fx0 = floor(mx), fy0 = floor(my);
        const float16 fx = mx - fx0, fy = my - fy0;
        const int16 x0 = convert_int16(fx0), y0 = convert_int16(fy0);
        const float16 z = (float16)(0.0f);
        const float16 wx0 = select(z, 1.0f - fx, x0 >= 0 && x0 < W);
        const float16 wx1 = select(z, fx, x0 + 1 >= 0 && x0 + 1 < W);
        const float16 wy0 = select(z, 1.0f - fy, y0 >= 0 && y0 < H);
        const float16 wy1 = select(z, fy, y0 + 1 >= 0 && y0 + 1 < H);
        const int16 xa = clamp(x0, 0, W - 1), xb = clamp(x0 + 1, 0, W - 1);
        const int16 ra = clamp(y0, 0, H - 1) * W, rb = clamp(y0 + 1, 0, H - 1) * W;
        const float16 w00 = wy0 * wx0, w01 = wy0 * wx1, w10 = wy1 * wx0, w11 = wy1 * wx1;
        /* Smooth motion (a pan, a zoom: the common case) reads the 16 lanes' taps from a few
         * rows at nearly consecutive columns: each lane's source column is xa.s0 + k + dx with
         * dx in {dlo, dlo + 1}, its rows in {r0, r1} (+ rstep for the lower tap). Then vector
         * loads at three column offsets per row and selects replace the 4 x 16 gathers. */
        const int16 iota = (int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
        const int16 dx = xa - (xa.s0 + iota);
        const int dlo = hmin16(dx), r0 = hmin16(ra), r1 = hmax16(ra), rstep = rb.s0 - ra.s0;
        const int16 hi_col = dx != dlo, hi_row = ra != r0;
        const bool smooth = all(dx == dlo || dx == dlo + 1) && all(xb == xa + 1)
                            && all(ra == r0 || ra == r1) && all(rb - ra == rstep)
                            && xa.s0 + dlo + 17 < W;
        const int c0 = xa.s0 + dlo;
        for (int c = 0; c < 3; ++c) {
            __global const float *sp = src + (size_t)c * npix, *bp = base_prev + (size_t)c * npix;
            float16 v00, v01, v10, v11;
            if (smooth) {
                row_taps(sp, r0 + c0, r1 + c0, hi_col, hi_row, &v00, &v01);
                row_taps(sp, r0 + rstep + c0, r1 + rstep + c0, hi_col, hi_row, &v10, &v11);
                if (base) {
                    float16 b00, b01, b10, b11;
                    row_taps(bp, r0 + c0, r1 + c0, hi_col, hi_row, &b00, &b01);
                    row_taps(bp, r0 + rstep + c0, r1 + rstep + c0, hi_col, hi_row, &b10, &b11);
                    v00 -= b00; v01 -= b01; v10 -= b10; v11 -= b11;
                }
            } else {
                v00 = gather16(sp, ra + xa); v01 = gather16(sp, ra + xb);
                v10 = gather16(sp, rb + xa); v11 = gather16(sp, rb + xb);
                if (base) {
                    v00 -= gather16(bp, ra + xa); v01 -= gather16(bp, ra + xb);
                    v10 -= gather16(bp, rb + xa); v11 -= gather16(bp, rb + xb);
                }
            }
            float16 o = z;
            o += w00 * v00;
            o += w01 * v01;
            o += w10 * v10;
            o += w11 * v11;
            if (base) o += vload16(0, base_new + (size_t)c * npix + i0);
            out[c] = o;
        }
    }
    for (int c = 0; c < 3; ++c) {
        const size_t j = (size_t)c * npix + i0;
        float16 o = select(vload16(0, fallback + j), out[c], ok);
        if (flags & CARRY_CLAMP) o = clamp(o, 0.0f, 1.0f);
        vstore16(o, 0, dst + j);
    }
}
#endif

__kernel __attribute__((reqd_work_group_size(WG, 1, 1)))
void carry(__global const float *restrict src, __global const float *restrict base_prev,
           __global const float *base_new, __global const float *fallback,
           __global const float2 *restrict map, __global const uchar *restrict valid,
           __global float *dst, __global const float *restrict src2, __global float *dst2,
           const int flags, const int H, const int W)
{
    const int i0 = get_global_id(0) * VEC;
    const bool two = flags & CARRY_TWO;
#if VEC == 16
    if (i0 + 16 <= H * W) {
        carry16(src, base_prev, base_new, fallback, map, valid, dst, flags, H, W, i0);
        if (two)
            carry16(src2, base_prev, base_new, fallback, map, valid, dst2, flags, H, W, i0);
        return;
    }
#endif
    const int i1 = min(i0 + VEC, H * W);
    for (int i = i0; i < i1; ++i) {
        carry_pixel(src, base_prev, base_new, fallback, map, valid, dst, flags, H, W, i);
        if (two)
            carry_pixel(src2, base_prev, base_new, fallback, map, valid, dst2, flags, H, W, i);
    }
}
