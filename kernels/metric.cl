/* metric.cl - the perceptual distance of the solve (paper Eq. 4, DESIGN.md §3) on the device.
 * NumPy twin: rtdefocus/reference/metric.py.
 *
 *   e      = F P - I                                  planar RGB residual
 *   Q e    = A0 e + A1 Lap(e)                         A0 = M^T diag(w1,w2,w2) M, A1 = M^T diag(w3,w4,w4) M
 *   Lap(e) = sum over in-frame 4-neighbours j of (e(x) - e(j))   (= grad^T grad, Neumann border)
 *   d      = sum_x <e(x), (Q e)(x)>                   (= Eq. 4: w1 |e_Y|^2 + w2 |e_C|^2 + w3 |grad e_Y|^2
 *                                                         + w4 |grad e_C|^2, spatial sign corrected)
 * The gradient of d is 2 F^T (Q e): these kernels produce the "pre-adjoint field" q = Q e and
 * the first stage of the reductions the line search needs (solver.cl:reduce_partials does the
 * second stage).
 *
 * With HAS_SCALE (the surface's albedo folded into the operator, surface="flatten"; DESIGN.md §3):
 * a per-pixel, per-channel scale S (float32 (3, H, W), argument `scale`) multiplies every residual,
 * e = S (fp - target) and e = S fs, and the field is q = S Q e, so that 2 F^T q is the gradient of
 * d(S (F P - target)). The <fs, v> of metric_curvature stays unscaled (v = q already carries S).
 * Without it `scale` is never read (any buffer will do).
 *
 *   metric_residual(fp, target, q, scale, partials, H, W)       e = fp - target; writes q
 *   metric_update(fp, fs, t, target, fp_out, q, scale, partials, H, W)
 *                                                               fp_out = fp + t fs, e = fp_out - target;
 *                                                               writes fp_out and q
 *   metric_curvature(fs, v, with_dot, scale, partials, H, W)    e = fs; writes nothing but partials
 *   partials[0 * n_groups + g] = work-group g's share of <e, Q e>
 *   partials[1 * n_groups + g] = its share of <e, v> (metric_curvature with with_dot != 0; else 0)
 *
 * Images: planar float32 (3, H, W), row-major, linear light, channel stride H*W; t float; H, W int.
 * n_groups = number of work-groups, numbered row-major. Two variants of the same maths (-D):
 *
 * VARIANT_GPU - one work-item per pixel. Global size (ceil(W/LX)*LX, ceil(H/LY)*LY), local (LX, LY).
 * VARIANT_CPU - one work-item per 16-pixel row chunk, explicit float16 vectors (the shape a CPU's
 *   SIMD units want). Global size (ceil(ceil(W/16)/LX)*LX, ceil(H/LY)*LY), local (LX, LY).
 *
 * With COLOUR_PC (FISTA's field; twin NumpyOps.metric_residual(colour=True)): the field written
 * is C Q e with the 3x3 colour preconditioner C (-D PC_rc, rtdefocus.reference.metric
 * Metric.colour_preconditioner); the distance <e, Q e> is unchanged. Not with HAS_SCALE.
 *
 * Constants (-D): A0_rc, A1_rc for r, c in 0..2 (float literals), HAS_SPATIAL (0: no Laplacian,
 * e.g. the per-channel RGB metric), HAS_SCALE (0/1, default 0), VARIANT_GPU or VARIANT_CPU, LX, LY
 * (LX*LY a power of two).
 */
#include "common.h"

#if !defined(LX) || !defined(LY) || !defined(HAS_SPATIAL)
#error "metric.cl needs -D LX, LY, HAS_SPATIAL, A0_rc/A1_rc and VARIANT_CPU or VARIANT_GPU"
#endif
#define WG (LX * LY)
#ifndef HAS_SCALE
#define HAS_SCALE 0
#endif

#ifndef COLOUR_PC
#define COLOUR_PC 0
#endif
#if COLOUR_PC && HAS_SCALE
#error "metric.cl: COLOUR_PC is not defined for a residual scale (HAS_SCALE)"
#endif

#define MODE_RESIDUAL 0   /* e = a - c          */
#define MODE_UPDATE 1     /* e = (a + t b) - c  */
#define MODE_PLAIN 2      /* e = a              */

/* Both quantities of a work-group into partials (common.h: wg_sum4, store_partials). */
inline void reduce_group(__local float4 *scratch, const float2 acc, __global float *partials)
{
    store_partials(partials, wg_sum4(scratch, (float4)(acc, 0.0f, 0.0f), WG), 2);
}

#if defined(VARIANT_GPU)
/* ------------------------------------------------------------------ one work-item per pixel */

/* The residual at pixel i, all three channels; `mode` is a literal at every call site. */
inline float3 e_at(const int mode, __global const float *restrict a, __global const float *restrict b,
                   const float t, __global const float *restrict c, __global const float *restrict sc,
                   const size_t i, const size_t hw)
{
    float3 v = (float3)(a[i], a[i + hw], a[i + 2 * hw]);
    if (mode == MODE_UPDATE) v += t * (float3)(b[i], b[i + hw], b[i + 2 * hw]);
    if (mode != MODE_PLAIN) v -= (float3)(c[i], c[i + hw], c[i + 2 * hw]);
#if HAS_SCALE
    v *= (float3)(sc[i], sc[i + hw], sc[i + 2 * hw]);
#endif
    return v;
}

#define MAT3(A, v) ((float3)(A##_00 * (v).x + A##_01 * (v).y + A##_02 * (v).z, \
                             A##_10 * (v).x + A##_11 * (v).y + A##_12 * (v).z, \
                             A##_20 * (v).x + A##_21 * (v).y + A##_22 * (v).z))

/* Q e at (x, y) from the residual there (`e`) and at its in-frame neighbours. */
inline float3 q_at(const int mode, __global const float *restrict a, __global const float *restrict b,
                   const float t, __global const float *restrict c, __global const float *restrict sc,
                   const int x, const int y, const int H, const int W, const float3 e)
{
    float3 q = MAT3(A0, e);
#if HAS_SPATIAL
    const size_t hw = (size_t)H * W, i = IDX((size_t)y, x, W);
    float3 lap = (float3)(0.0f);
    if (x > 0) lap += e - e_at(mode, a, b, t, c, sc, i - 1, hw);
    if (x < W - 1) lap += e - e_at(mode, a, b, t, c, sc, i + 1, hw);
    if (y > 0) lap += e - e_at(mode, a, b, t, c, sc, i - W, hw);
    if (y < H - 1) lap += e - e_at(mode, a, b, t, c, sc, i + W, hw);
    q += MAT3(A1, lap);
#endif
    return q;
}

inline void store3(__global float *restrict dst, const size_t i, const size_t hw, const float3 v)
{
    dst[i] = v.x;
    dst[i + hw] = v.y;
    dst[i + 2 * hw] = v.z;
}

/* One pixel of any mode: returns (<e, Qe>, <e, v>) and writes q / fp_out when given. */
inline float2 metric_pixel(const int mode, __global const float *restrict a,
                           __global const float *restrict b, const float t,
                           __global const float *restrict c, __global float *restrict a_out,
                           __global float *restrict q, __global const float *restrict v,
                           const int with_dot, __global const float *restrict sc, const int H,
                           const int W)
{
    const int x = get_global_id(0), y = get_global_id(1);
    float2 acc = (float2)(0.0f);
    if (x < W && y < H) {
        const size_t hw = (size_t)H * W, i = IDX((size_t)y, x, W);
        const float3 e = e_at(mode, a, b, t, c, sc, i, hw);
        const float3 qv = q_at(mode, a, b, t, c, sc, x, y, H, W, e);
        if (mode == MODE_UPDATE)
            store3(a_out, i, hw, (float3)(a[i], a[i + hw], a[i + 2 * hw])
                                 + t * (float3)(b[i], b[i + hw], b[i + 2 * hw]));
#if HAS_SCALE
        if (mode != MODE_PLAIN)
            store3(q, i, hw, qv * (float3)(sc[i], sc[i + hw], sc[i + 2 * hw]));
        acc.x = dot(e, qv);
        if (with_dot) acc.y = dot((float3)(a[i], a[i + hw], a[i + 2 * hw]),
                                  (float3)(v[i], v[i + hw], v[i + 2 * hw]));
#else
#if COLOUR_PC
        if (mode != MODE_PLAIN) store3(q, i, hw, MAT3(PC, qv));
#else
        if (mode != MODE_PLAIN) store3(q, i, hw, qv);
#endif
        acc.x = dot(e, qv);
        if (with_dot) acc.y = dot(e, (float3)(v[i], v[i + hw], v[i + 2 * hw]));
#endif
    }
    return acc;
}

#else
/* ------------------------------------------------------------------ 16-pixel row chunks (CPU) */
#if !defined(VARIANT_CPU)
#error "metric.cl needs -D VARIANT_CPU or -D VARIANT_GPU"
#endif

/* Unaligned 16-float loads/stores: a vector type with 4-byte alignment makes LLVM emit one
 * unaligned vector move (PoCL's vload16 assembles it from 8-byte pieces). */
typedef float16 __attribute__((aligned(4))) float16_u;
#define GLD16(p) (*(__global const float16_u *)(p))
#define GST16(p, v) (*(__global float16_u *)(p) = (v))

/* p[row + xs .. row + xs + 15], 0 outside [0, W). */
inline float16 ld16(__global const float *restrict p, const size_t row, const int xs, const int W)
{
    if (xs >= 0 && xs + 16 <= W) return GLD16(p + row + xs);
    float tmp[16];
    for (int j = 0; j < 16; ++j) tmp[j] = (xs + j >= 0 && xs + j < W) ? p[row + xs + j] : 0.0f;
    return vload16(0, tmp);
}

inline void st16(__global float *restrict p, const size_t row, const int xs, const int W, const float16 v)
{
    if (xs + 16 <= W) { GST16(p + row + xs, v); return; }
    float tmp[16];
    vstore16(v, 0, tmp);
    for (int j = 0; j < 16 && xs + j < W; ++j) p[row + xs + j] = tmp[j];
}

inline float16 e16(const int mode, __global const float *restrict a, __global const float *restrict b,
                   const float t, __global const float *restrict c, __global const float *restrict sc,
                   const size_t row, const int xs, const int W)
{
    float16 v = ld16(a, row, xs, W);
    if (mode == MODE_UPDATE) v += t * ld16(b, row, xs, W);
    if (mode != MODE_PLAIN) v -= ld16(c, row, xs, W);
#if HAS_SCALE
    v *= ld16(sc, row, xs, W);
#endif
    return v;
}

#define MATROW(A, r, v0, v1, v2) (A##_##r##0 * (v0) + A##_##r##1 * (v1) + A##_##r##2 * (v2))

inline float2 metric_pixel(const int mode, __global const float *restrict a,
                           __global const float *restrict b, const float t,
                           __global const float *restrict c, __global float *restrict a_out,
                           __global float *restrict q, __global const float *restrict v,
                           const int with_dot, __global const float *restrict sc, const int H,
                           const int W)
{
    const int x0 = get_global_id(0) * 16, y = get_global_id(1);
    float2 acc = (float2)(0.0f);
    if (x0 >= W || y >= H) return acc;
    const size_t hw = (size_t)H * W, row = (size_t)y * W;
    const int16 xi = x0 + (int16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    const int16 inside = xi < W;
    float16 e[3], lap[3];
    for (int k = 0; k < 3; ++k) {
        const size_t r = k * hw + row;
        e[k] = e16(mode, a, b, t, c, sc, r, x0, W);
#if HAS_SPATIAL
        /* A missing neighbour (frame border) contributes nothing: stand in the pixel itself. */
        const float16 l = select(e[k], e16(mode, a, b, t, c, sc, r, x0 - 1, W), xi - 1 >= 0);
        const float16 rr = select(e[k], e16(mode, a, b, t, c, sc, r, x0 + 1, W), xi + 1 < W);
        const float16 u = y > 0 ? e16(mode, a, b, t, c, sc, r - W, x0, W) : e[k];
        const float16 d = y < H - 1 ? e16(mode, a, b, t, c, sc, r + W, x0, W) : e[k];
        lap[k] = 4.0f * e[k] - l - rr - u - d;
#else
        lap[k] = (float16)(0.0f);
#endif
    }
    float16 dsum = (float16)(0.0f);
#if COLOUR_PC
    float16 qv[3];
#endif
    for (int k = 0; k < 3; ++k) {
        float16 qk;
        if (k == 0) qk = MATROW(A0, 0, e[0], e[1], e[2]);
        else if (k == 1) qk = MATROW(A0, 1, e[0], e[1], e[2]);
        else qk = MATROW(A0, 2, e[0], e[1], e[2]);
#if HAS_SPATIAL
        if (k == 0) qk += MATROW(A1, 0, lap[0], lap[1], lap[2]);
        else if (k == 1) qk += MATROW(A1, 1, lap[0], lap[1], lap[2]);
        else qk += MATROW(A1, 2, lap[0], lap[1], lap[2]);
#endif
        const size_t r = k * hw + row;
        if (mode == MODE_UPDATE) st16(a_out, r, x0, W, ld16(a, r, x0, W) + t * ld16(b, r, x0, W));
#if HAS_SCALE
        if (mode != MODE_PLAIN) st16(q, r, x0, W, qk * ld16(sc, r, x0, W));
        dsum += e[k] * qk;
        if (with_dot)
            acc.y += hsum16(select((float16)(0.0f), ld16(a, r, x0, W) * ld16(v, r, x0, W), inside));
#else
#if COLOUR_PC
        qv[k] = qk;                       /* stored below, once all three channels are known */
#else
        if (mode != MODE_PLAIN) st16(q, r, x0, W, qk);
#endif
        dsum += e[k] * qk;
        if (with_dot) acc.y += hsum16(select((float16)(0.0f), e[k] * ld16(v, r, x0, W), inside));
#endif
    }
#if COLOUR_PC
    if (mode != MODE_PLAIN) {
        st16(q, row, x0, W, MATROW(PC, 0, qv[0], qv[1], qv[2]));
        st16(q, hw + row, x0, W, MATROW(PC, 1, qv[0], qv[1], qv[2]));
        st16(q, 2 * hw + row, x0, W, MATROW(PC, 2, qv[0], qv[1], qv[2]));
    }
#endif
    acc.x = hsum16(select((float16)(0.0f), dsum, inside));
    return acc;
}
#endif

/* q = Q (fp - target); partials[0] += <e, q>.
 * fp, target: float32 (3, H, W) in; q: float32 (3, H, W) out. */
__kernel __attribute__((reqd_work_group_size(LX, LY, 1)))
void metric_residual(__global const float *restrict fp, __global const float *restrict target,
                     __global float *restrict q, __global const float *restrict scale,
                     __global float *restrict partials, const int H, const int W)
{
    __local float4 scratch[WG];
    const float2 acc = metric_pixel(MODE_RESIDUAL, fp, fp, 0.0f, target, q, q, fp, 0, scale, H, W);
    reduce_group(scratch, acc, partials);
}

/* The line-search update of the blurred image and the new field in one pass:
 * fp_out = fp + t fs;  q = Q (fp_out - target);  partials[0] += <e, q>.
 * fp, fs, target: float32 (3, H, W) in; fp_out (distinct from fp), q: float32 (3, H, W) out. */
__kernel __attribute__((reqd_work_group_size(LX, LY, 1)))
void metric_update(__global const float *restrict fp, __global const float *restrict fs, const float t,
                   __global const float *restrict target, __global float *restrict fp_out,
                   __global float *restrict q, __global const float *restrict scale,
                   __global float *restrict partials, const int H, const int W)
{
    __local float4 scratch[WG];
    const float2 acc = metric_pixel(MODE_UPDATE, fp, fs, t, target, fp_out, q, fp, 0, scale, H, W);
    reduce_group(scratch, acc, partials);
}

/* The curvature of d along a direction s, from fs = F s: partials[0] += <fs, Q fs>; with
 * with_dot != 0 also partials[1] += <fs, v> (v: float32 (3, H, W), e.g. the field q). */
__kernel __attribute__((reqd_work_group_size(LX, LY, 1)))
void metric_curvature(__global const float *restrict fs, __global const float *restrict v,
                      const int with_dot, __global const float *restrict scale,
                      __global float *restrict partials, const int H, const int W)
{
    __local float4 scratch[WG];
    const float2 acc = metric_pixel(MODE_PLAIN, fs, fs, 0.0f, fs, partials, partials, v,
                                    with_dot, scale, H, W);
    reduce_group(scratch, acc, partials);
}

/* FISTA's spatial preconditioner (twin: rtdefocus.reference.ops.boost_field):
 *   out = M_F g,  M = I + grad^T Gamma grad  (a weighted graph Laplacian: symmetric, M >= I),
 * applied per channel to the gradient g = F^T q at the iterate P on its free set F: an element
 * at a bound whose gradient pushes it out (P <= 0 and g > 0, or P >= 1 and g < 0) is active; it
 * keeps its plain g and counts as 0 for its free neighbours (so the fixed point is still the
 * constrained optimum). Edge weights: gx[y, x] between (x, y) and (x + 1, y) (0 in the last
 * column), gy[y, x] between (x, y) and (x, y + 1) (0 in the last row); float32 (H, W).
 *   boost_gradient(P, g, gx, gy, out, H, W)   P, g, out: float32 (3, H, W); out distinct from g.
 * Same launch shape as the metric kernels. */
#if defined(VARIANT_GPU)
/* Element at a bound that its gradient v pushes out (the free set's complement). */
inline bool active(const float p, const float v)
{
    return (p <= 0.0f && v > 0.0f) || (p >= 1.0f && v < 0.0f);
}

inline float free_g(__global const float *restrict P, __global const float *restrict g,
                    const size_t i)
{
    return active(P[i], g[i]) ? 0.0f : g[i];
}

__kernel __attribute__((reqd_work_group_size(LX, LY, 1)))
void boost_gradient(__global const float *restrict P, __global const float *restrict g,
                    __global const float *restrict gx, __global const float *restrict gy,
                    __global float *restrict out, const int H, const int W)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= W || y >= H) return;
    const size_t hw = (size_t)H * W, j = IDX((size_t)y, x, W);
    const float wl = x > 0 ? gx[j - 1] : 0.0f, wr = gx[j];
    const float wu = y > 0 ? gy[j - W] : 0.0f, wd = gy[j];
    for (int k = 0; k < 3; ++k) {
        const size_t i = k * hw + j;
        const float p = P[i], f = g[i];
        float o = f;
        if (!active(p, f)) {
            if (x > 0) o += wl * (f - free_g(P, g, i - 1));
            if (x < W - 1) o += wr * (f - free_g(P, g, i + 1));
            if (y > 0) o += wu * (f - free_g(P, g, i - W));
            if (y < H - 1) o += wd * (f - free_g(P, g, i + W));
        }
        out[i] = o;      /* an active element keeps its plain g */
    }
}
#else
/* Lanes at a bound that their gradient v pushes out (the free set's complement). */
inline int16 active16(const float16 p, const float16 v)
{
    return (p <= 0.0f & v > 0.0f) | (p >= 1.0f & v < 0.0f);
}

/* g with its active elements zeroed, at pixels xs .. xs + 15 of row offset r (0 outside). */
inline float16 free16(__global const float *restrict P, __global const float *restrict g,
                      const size_t r, const int xs, const int W)
{
    const float16 v = ld16(g, r, xs, W);
    return select(v, (float16)(0.0f), active16(ld16(P, r, xs, W), v));
}

__kernel __attribute__((reqd_work_group_size(LX, LY, 1)))
void boost_gradient(__global const float *restrict P, __global const float *restrict g,
                    __global const float *restrict gx, __global const float *restrict gy,
                    __global float *restrict out, const int H, const int W)
{
    const int x0 = get_global_id(0) * 16, y = get_global_id(1);
    if (x0 >= W || y >= H) return;
    const size_t hw = (size_t)H * W, row = (size_t)y * W;
    /* edge weights (ld16 gives 0 outside the frame: no edge there) */
    const float16 wl = ld16(gx, row, x0 - 1, W), wr = ld16(gx, row, x0, W);
    const float16 wu = y > 0 ? ld16(gy, row - W, x0, W) : (float16)(0.0f);
    const float16 wd = ld16(gy, row, x0, W);
    for (int k = 0; k < 3; ++k) {
        const size_t r = k * hw + row;
        const float16 v = ld16(g, r, x0, W);
        const int16 act = active16(ld16(P, r, x0, W), v);
        const float16 f = select(v, (float16)(0.0f), act);
        float16 o = f + wl * (f - free16(P, g, r, x0 - 1, W)) + wr * (f - free16(P, g, r, x0 + 1, W));
        if (y > 0) o += wu * (f - free16(P, g, r - W, x0, W));
        if (y < H - 1) o += wd * (f - free16(P, g, r + W, x0, W));
        st16(out, r, x0, W, select(o, v, act));
    }
}
#endif
