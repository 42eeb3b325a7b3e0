/* blur.cl - the spatially varying blur F (forward) and its exact adjoint F^T (DESIGN.md §3,
 * docs/internals.md "Kernel field F"; NumPy twin: rtdefocus/reference/blur.py).
 *
 *   k_x(u)          = sum_j wts[x, j] * psi_{idx[x, j]}(u)       (<= 4 measured PSFs per pixel)
 *   forward  O(x)   = sum_u k_x(u) P(x - u)                     (P = 0 outside the frame)
 *   adjoint  A(y)   = sum_u k_{y+u}(u) r(y + u)                  (y + u inside the frame)
 *   psi_n(u, v)     = psfs[n, RADIUS + v, RADIUS + u]            (image of a dot, not flipped)
 *
 * Images: planar float32 (CHANNELS, H, W), row-major, linear light; the same F on every channel.
 * Two variants of the same maths, chosen by -D:
 *
 * VARIANT_GPU - one work-item per output pixel; the work-group's input tile plus a RADIUS halo
 *   sits in local memory. Global size (ceil(W/TILE_X)*TILE_X, ceil(H/TILE_Y)*TILE_Y), local size
 *   (TILE_X, TILE_Y) exactly (reqd_work_group_size).
 *   blur_forward_gpu(src, dst, psfs, idx, wts, H, W)
 *   blur_adjoint_gpu(src, dst, psfs, idx, wts, H, W)
 *     src, dst  float32 (CHANNELS, H, W)
 *     psfs      float32 (N, K, K)
 *     idx       int32   (H, W, 4) read as int4 per pixel
 *     wts       float32 (H, W, 4) read as float4 per pixel
 *
 * VARIANT_CPU - each work-item computes a 16-pixel row chunk (forward) or a column of ROWS_COL
 *   rows of one (adjoint) with explicit float16 vectors, broadcasting the taps of the few PSFs
 *   active there; see the section's own comment for its arguments and sizes.
 *
 * Constants (-D): K (odd kernel size), RADIUS = K / 2, CHANNELS (1 or 3), VARIANT_GPU or
 * VARIANT_CPU, and per variant TILE_X, TILE_Y, or LX, LY (work-group), HALO, ROWS_ADJ,
 * ROWS_COL, RING.
 */
#include "common.h"

#ifndef K
#error "blur.cl needs -D K=<odd kernel size>"
#endif
#define KK (K * K)

#if defined(VARIANT_GPU)

#define TW (TILE_X + 2 * RADIUS)
#define TH (TILE_Y + 2 * RADIUS)

/* Fill a (TH, TW) local tile whose (0, 0) is frame pixel (y0 - RADIUS, x0 - RADIUS), for every
 * channel, with 0 outside the frame. Called by the whole work-group. */
inline void load_tile(__local float *tile, __global const float *restrict src,
                      const int y0, const int x0, const int H, const int W)
{
    const int lid = get_local_id(1) * TILE_X + get_local_id(0);
    for (int i = lid; i < TH * TW; i += TILE_X * TILE_Y) {
        const int ty = i / TW, tx = i - ty * TW;
        const int y = y0 - RADIUS + ty, x = x0 - RADIUS + tx;
        const bool in = y >= 0 && y < H && x >= 0 && x < W;
        for (int c = 0; c < CHANNELS; ++c)
            tile[c * TH * TW + i] = in ? src[(size_t)c * H * W + IDX(y, x, W)] : 0.0f;
    }
}

__kernel __attribute__((reqd_work_group_size(TILE_X, TILE_Y, 1)))
void blur_forward_gpu(__global const float *restrict src, __global float *restrict dst,
                      __global const float *restrict psfs, __global const int4 *restrict idx,
                      __global const float4 *restrict wts, const int H, const int W)
{
    __local float tile[CHANNELS * TH * TW];
    const int lx = get_local_id(0), ly = get_local_id(1);
    const int x0 = get_group_id(0) * TILE_X, y0 = get_group_id(1) * TILE_Y;
    load_tile(tile, src, y0, x0, H, W);
    barrier(CLK_LOCAL_MEM_FENCE);
    const int x = x0 + lx, y = y0 + ly;
    if (x >= W || y >= H) return;

    const int4 id = idx[IDX(y, x, W)];
    const float4 w = wts[IDX(y, x, W)];
    __global const float *p0 = psfs + id.s0 * KK, *p1 = psfs + id.s1 * KK;
    __global const float *p2 = psfs + id.s2 * KK, *p3 = psfs + id.s3 * KK;
    float acc[CHANNELS];
    for (int c = 0; c < CHANNELS; ++c) acc[c] = 0.0f;
    for (int v = -RADIUS; v <= RADIUS; ++v) {
        for (int u = -RADIUS; u <= RADIUS; ++u) {
            const int t = (RADIUS + v) * K + RADIUS + u;
            const float kx = w.s0 * p0[t] + w.s1 * p1[t] + w.s2 * p2[t] + w.s3 * p3[t];
            const int l = (ly + RADIUS - v) * TW + lx + RADIUS - u;     /* P(x - u) */
            for (int c = 0; c < CHANNELS; ++c) acc[c] += kx * tile[c * TH * TW + l];
        }
    }
    for (int c = 0; c < CHANNELS; ++c) dst[(size_t)c * H * W + IDX(y, x, W)] = acc[c];
}

__kernel __attribute__((reqd_work_group_size(TILE_X, TILE_Y, 1)))
void blur_adjoint_gpu(__global const float *restrict src, __global float *restrict dst,
                      __global const float *restrict psfs, __global const int4 *restrict idx,
                      __global const float4 *restrict wts, const int H, const int W)
{
    /* r, and the kernel field (indices, weights), over the tile plus halo: the adjoint at y
     * needs k_{y+u}, the kernels of the *neighbours*. */
    __local float tile[CHANNELS * TH * TW];
    __local int4 tid[TH * TW];
    __local float4 twt[TH * TW];
    const int lx = get_local_id(0), ly = get_local_id(1);
    const int x0 = get_group_id(0) * TILE_X, y0 = get_group_id(1) * TILE_Y;
    load_tile(tile, src, y0, x0, H, W);
    const int lid = ly * TILE_X + lx;
    for (int i = lid; i < TH * TW; i += TILE_X * TILE_Y) {
        const int ty = i / TW, tx = i - ty * TW;
        const int yy = y0 - RADIUS + ty, xx = x0 - RADIUS + tx;
        const bool in = yy >= 0 && yy < H && xx >= 0 && xx < W;
        tid[i] = in ? idx[IDX(yy, xx, W)] : (int4)(0);
        twt[i] = in ? wts[IDX(yy, xx, W)] : (float4)(0.0f);
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    const int x = x0 + lx, y = y0 + ly;
    if (x >= W || y >= H) return;

    float acc[CHANNELS];
    for (int c = 0; c < CHANNELS; ++c) acc[c] = 0.0f;
    for (int v = -RADIUS; v <= RADIUS; ++v) {
        for (int u = -RADIUS; u <= RADIUS; ++u) {
            const int t = (RADIUS + v) * K + RADIUS + u;
            const int l = (ly + RADIUS + v) * TW + lx + RADIUS + u;     /* x = y + u */
            const int4 id = tid[l];
            const float4 w = twt[l];
            const float kx = w.s0 * psfs[id.s0 * KK + t] + w.s1 * psfs[id.s1 * KK + t]
                           + w.s2 * psfs[id.s2 * KK + t] + w.s3 * psfs[id.s3 * KK + t];
            for (int c = 0; c < CHANNELS; ++c) acc[c] += kx * tile[c * TH * TW + l];
        }
    }
    for (int c = 0; c < CHANNELS; ++c) dst[(size_t)c * H * W + IDX(y, x, W)] = acc[c];
}

#endif /* VARIANT_GPU */

#if defined(VARIANT_CPU)
/* VARIANT_CPU. Row chunks of 16 pixels; NCH = ceil(W / 16) chunks per row. Per chunk the host
 * lists the distinct PSFs with a nonzero weight there, in groups of 4 ("chunk groups"):
 *   goff  int32 (H * NCH + 1)   groups of chunk (y, cx) are goff[y*NCH+cx] .. goff[y*NCH+cx+1]-1
 *   gids  int32 (G, 4)          PSF ids of a group, -1 for an empty slot
 *   gw    float32 (G, 4, 16)    weight of each id at each of the chunk's 16 pixels (0 past W)
 * so that k_x = sum over the chunk's groups g and slots s of gw[g, s, x - x0] * psi_{gids[g, s]}.
 * Within a group the taps are blended per pixel, t(u) = sum_s w_s * psi_s(u) (4 vector FMAs with
 * broadcast taps), then applied to every channel: one pass over the K*K taps per group.
 *
 *   gext int32 (G, K): per chunk group and kernel row RADIUS + v, the largest |u| of a nonzero
 *   tap in any of the group's PSFs (-1: the row is zero in all of them); taps beyond are
 *   skipped (the zero corners of disk-shaped PSFs, and the rows beyond their support).
 *   asup int32 (GA), aext int32 (GA, K): per column-block group, the widest support
 *   half-width of its PSFs (<= RADIUS; the input rows it reaches) and the row extents as gext.
 * blur_forward_cpu(src, dst, psfs, goff, gids, gw, gext, H, W, NCH)
 *   global size (ceil(NCH / LX) * LX, ceil(H / LY) * LY), local (LX, LY): one chunk per item.
 * blur_adjoint_cpu(src, dst, psfs, goff, gids, gw, agoff, agids, arows, asup, aext, H, W,
 *                  NCH, NBY)
 *   global size (ceil(NCH / LX) * LX, ceil(NBY / LY) * LY), NBY = ceil(H / ROWS_COL): one
 *   column block of ROWS_COL rows x 16 pixels per item. The adjoint at y needs the kernels of
 *   y's neighbours, A(y) = sum_u [sum_s W_s(y+u) psi_s(u)] r(y+u), so the host also lists per
 *   column block the distinct PSFs over the block plus its RADIUS reach, in groups of 4:
 *     agoff int32 (NBY * NCH + 1), agids int32 (GA, 4)   as goff / gids
 *     arows int32 (GA, 2)   first and last input row where the group's PSFs have weight there
 *   and their weights W_s over the reach are rebuilt from the chunk groups. Input rows (r and
 *   W_s, as float16 vectors) go through a ring of RING rows, built once per column; each one
 *   serves ROWS_ADJ output rows accumulated together (the adjoint is load-bound otherwise).
 */
#define CW 16
/* HALO = 8 * ceil(RADIUS / 8) (>= RADIUS, -D from the host): a row segment x0 - HALO ...
 * x0 + 15 + HALO covers every tap and is a whole number NV of float16 vectors (2 for r <= 8) */
#define SEG (CW + 2 * HALO)
#define NV (SEG / CW)
#define CHALO ((HALO + CW - 1) / CW)     /* chunks either side that the segment touches */

/* Unaligned 16-float loads/stores. PoCL's vload16 assembles them from 8-byte pieces; a vector
 * type with 4-byte alignment makes LLVM emit one unaligned vector move (vmovups). */
typedef float16 __attribute__((aligned(4))) float16_u;
#define LD16(p) (*(const float16_u *)(p))
#define GLD16(p) (*(__global const float16_u *)(p))
#define GST16(p, v) (*(__global float16_u *)(p) = (v))

/* Lanes s .. s + 15 of the 32-lane concatenation (a, b), s in [0, 16). The tap loops are
 * unrolled, so s is a constant there and this folds to one two-source permute: shifted windows
 * come from registers instead of one unaligned load per tap and channel. */
inline float16 window(const float16 a, const float16 b, const int s)
{
#if defined(__clang__)
    switch (s) {
    default: return a;
    case 1: return __builtin_shufflevector(a, b, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16);
    case 2: return __builtin_shufflevector(a, b, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17);
    case 3: return __builtin_shufflevector(a, b, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18);
    case 4: return __builtin_shufflevector(a, b, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19);
    case 5: return __builtin_shufflevector(a, b, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20);
    case 6: return __builtin_shufflevector(a, b, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21);
    case 7: return __builtin_shufflevector(a, b, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22);
    case 8: return __builtin_shufflevector(a, b, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23);
    case 9: return __builtin_shufflevector(a, b, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24);
    case 10: return __builtin_shufflevector(a, b, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25);
    case 11: return __builtin_shufflevector(a, b, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26);
    case 12: return __builtin_shufflevector(a, b, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27);
    case 13: return __builtin_shufflevector(a, b, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28);
    case 14: return __builtin_shufflevector(a, b, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29);
    case 15: return __builtin_shufflevector(a, b, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29, 30);
    }
#else   /* compilers without clang's builtin: the standard (slower) OpenCL shuffle */
    return shuffle2(a, b, (uint16)(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15) + (uint)s);
#endif
}
/* Pixels x0 - HALO + o ... + 15 of a segment held in vectors V[0 .. NV-1]. */
#define SEGV(V, o) window((V)[(o) / CW], (V)[(o) % CW ? (o) / CW + 1 : (o) / CW], (o) % CW)

/* V[k] = s[x0 - HALO + 16 k ... + 15] for k < NV, 0 outside [0, W). */
inline void load_segment(float16 *V, __global const float *restrict s, const int x0, const int W)
{
    if (x0 - HALO >= 0 && x0 + CW + HALO <= W) {
        #pragma unroll
        for (int k = 0; k < NV; ++k) V[k] = GLD16(s + x0 - HALO + k * CW);
    } else {                         /* first / last chunks of a row */
        float row[SEG];
        for (int i = 0; i < SEG; ++i) {
            const int x = x0 - HALO + i;
            row[i] = (x >= 0 && x < W) ? s[x] : 0.0f;
        }
        #pragma unroll
        for (int k = 0; k < NV; ++k) V[k] = LD16(row + k * CW);
    }
}

inline float16 load_chunk(__global const float *restrict d, const int x0, const int W)
{
    if (x0 + CW <= W) return GLD16(d + x0);
    float tmp[CW];
    for (int i = 0; i < CW; ++i) tmp[i] = x0 + i < W ? d[x0 + i] : 0.0f;
    return LD16(tmp);
}

inline void store_chunk(__global float *restrict d, const float16 v, const int x0, const int W)
{
    if (x0 + CW <= W) {
        GST16(d + x0, v);
    } else {
        float tmp[CW];
        vstore16(v, 0, tmp);
        for (int i = 0; i < W - x0; ++i) d[x0 + i] = tmp[i];
    }
}

__kernel __attribute__((reqd_work_group_size(LX, LY, 1)))
void blur_forward_cpu(__global const float *restrict src, __global float *restrict dst,
                      __global const float *restrict psfs, __global const int *restrict goff,
                      __global const int4 *restrict gids, __global const float *restrict gw,
                      __global const int *restrict gext, const int H, const int W, const int NCH)
{
    const int cx = get_global_id(0), y = get_global_id(1);
    if (cx >= NCH || y >= H) return;
    const int x0 = cx * CW;
    const size_t plane = (size_t)H * W;
    /* two accumulators per channel (even / odd u): one chain of K*K dependent FMAs would make
     * the forward latency-bound */
    float16 acc[2][CHANNELS];
    #pragma unroll
    for (int c = 0; c < CHANNELS; ++c) acc[0][c] = acc[1][c] = (float16)(0.0f);
    for (int g = goff[y * NCH + cx]; g < goff[y * NCH + cx + 1]; ++g) {
        const int erow = g * K + RADIUS + y;         /* gext[erow - yr]: row v = y - yr */
        const int ylo = max(y - RADIUS, 0), yhi = min(y + RADIUS, H - 1);
        const int4 id = max(gids[g], (int4)(0));     /* empty slots (-1) carry weight 0 */
        __global const float *p0 = psfs + id.s0 * KK, *p1 = psfs + id.s1 * KK;
        __global const float *p2 = psfs + id.s2 * KK, *p3 = psfs + id.s3 * KK;
        const float16 w0 = vload16(4 * g + 0, gw), w1 = vload16(4 * g + 1, gw);
        const float16 w2 = vload16(4 * g + 2, gw), w3 = vload16(4 * g + 3, gw);
        for (int yr = ylo; yr <= yhi; ++yr) {          /* input row yr = y - v */
            const int e = gext[erow - yr];              /* taps beyond |u| = e are zero */
            if (e < 0) continue;
            float16 V[CHANNELS][NV];
            #pragma unroll
            for (int c = 0; c < CHANNELS; ++c)
                load_segment(V[c], src + c * plane + (size_t)yr * W, x0, W);
            const int trow = (RADIUS + y - yr) * K + RADIUS;
            #pragma unroll
            for (int u = -RADIUS; u <= RADIUS; ++u) {
                if (u < -e || u > e) continue;
                const int t = trow + u;
                /* k_x(u, v) for the 16 pixels: the blend of this group's PSFs */
                const float16 kx = w0 * p0[t] + w1 * p1[t] + w2 * p2[t] + w3 * p3[t];
                #pragma unroll
                for (int c = 0; c < CHANNELS; ++c)                      /* P(x - u) */
                    acc[u & 1][c] = fma(kx, SEGV(V[c], HALO - u), acc[u & 1][c]);
            }
        }
    }
    #pragma unroll
    for (int c = 0; c < CHANNELS; ++c)
        store_chunk(dst + c * plane + (size_t)y * W, acc[0][c] + acc[1][c], x0, W);
}

/* Wv[s][k] = weight of PSF e.s_s at pixels (yr, x0 - HALO + 16 k ... + 15), from the chunk
 * groups (0 outside the frame and for the empty id -1). */
inline void weight_segment(float16 Wv[4][NV], const int4 e, const int yr, const int cx,
                           const int NCH, __global const int *restrict goff,
                           __global const int4 *restrict gids, __global const float *restrict gw)
{
    float16 ch[4][2 * CHALO + 1];    /* per chunk cx - CHALO ... cx + CHALO */
    #pragma unroll
    for (int k = 0; k < 2 * CHALO + 1; ++k) {
        const int cc = cx - CHALO + k;
        float16 a0 = (float16)(0.0f), a1 = a0, a2 = a0, a3 = a0;
        const int g0 = (cc >= 0 && cc < NCH) ? goff[yr * NCH + cc] : 0;
        const int g1 = (cc >= 0 && cc < NCH) ? goff[yr * NCH + cc + 1] : 0;
        if (g1 == g0 + 1 && all(gids[g0] == e)) {
            /* the usual case: the chunk has exactly this group's PSFs (both lists sorted) */
            a0 = vload16(4 * g0 + 0, gw); a1 = vload16(4 * g0 + 1, gw);
            a2 = vload16(4 * g0 + 2, gw); a3 = vload16(4 * g0 + 3, gw);
        } else {
            for (int g = g0; g < g1; ++g) {
                const int4 id = gids[g];
                #pragma unroll
                for (int s = 0; s < 4; ++s) {
                    const int ids = s == 0 ? id.s0 : s == 1 ? id.s1 : s == 2 ? id.s2 : id.s3;
                    const float16 wv = vload16(4 * g + s, gw);
                    /* 1 where this chunk slot holds the group's PSF j, else 0: no branches */
                    const float4 m = -convert_float4((int4)(ids) == e);
                    a0 = fma(wv, m.s0, a0); a1 = fma(wv, m.s1, a1);
                    a2 = fma(wv, m.s2, a2); a3 = fma(wv, m.s3, a3);
                }
            }
        }
        ch[0][k] = a0; ch[1][k] = a1; ch[2][k] = a2; ch[3][k] = a3;
    }
    /* the segment starts CHALO * 16 - HALO pixels into chunk cx - CHALO */
    #pragma unroll
    for (int s = 0; s < 4; ++s)
        #pragma unroll
        for (int k = 0; k < NV; ++k)
            Wv[s][k] = SEGV(ch[s], CHALO * CW - HALO + k * CW);
}


/* Input rows (r and the weights W_s of the group's PSFs) are kept in a ring of RING >= NR rows,
 * so that a column of ROWS_COL output rows builds each input row once, not NR / ROWS_ADJ times. */
#define NR (ROWS_ADJ + 2 * RADIUS)
#if ROWS_ADJ < 1 || ROWS_ADJ > 4
#error "blur_adjoint_cpu handles ROWS_ADJ = 1 ... 4"
#endif

/* acc[i] += sum_u [sum_s W_s(yr, x + u) psi_s(u, yr - y0 - i)] r(yr, x + u) for output rows
 * ILO <= i <= IHI, with input row yr = y0 - RADIUS + J (skipped outside ylo ... yhi: the
 * frame, and the rows where the group's PSFs have weight). */
#define ADJ_ROW(J, ILO, IHI)                                                               \
    {                                                                                      \
        const int yr = y0 - RADIUS + (J);                                                  \
        int em = -1;                     /* widest extent of the kernel rows J - i fed */  \
        _Pragma("unroll")                                                                  \
        for (int i = (ILO); i <= (IHI); ++i) em = max(em, ea[(J) - i]);                    \
        if (yr >= ylo && yr <= yhi && em >= 0) {                                           \
            const int slot = yr & (RING - 1);                                              \
            _Pragma("unroll")                                                              \
            for (int u = -RADIUS; u <= RADIUS; ++u) {                                      \
                if (u < -em || u > em) continue;                        /* zero taps */    \
                float16 rv[CHANNELS];                                   /* r(x + u) */     \
                _Pragma("unroll")                                                          \
                for (int c = 0; c < CHANNELS; ++c) rv[c] = SEGV(Vr[slot][c], HALO + u);    \
                const float16 v0 = SEGV(Wr[slot][0], HALO + u);                            \
                const float16 v1 = SEGV(Wr[slot][1], HALO + u);                            \
                const float16 v2 = SEGV(Wr[slot][2], HALO + u);                            \
                const float16 v3 = SEGV(Wr[slot][3], HALO + u);                            \
                _Pragma("unroll")                                                          \
                for (int i = (ILO); i <= (IHI); ++i) {                                     \
                    const int e = ea[(J) - i];   /* kernel row J - i: zero beyond |u| = e */ \
                    if (u < -e || u > e) continue;                                         \
                    const int t = ((J) - i) * K + RADIUS + u;     /* v = J - R - i */ \
                    const float16 kx = v0 * p0[t] + v1 * p1[t] + v2 * p2[t] + v3 * p3[t];   \
                    _Pragma("unroll")                                                      \
                    for (int c = 0; c < CHANNELS; ++c) acc[i][c] = fma(kx, rv[c], acc[i][c]); \
                }                                                                          \
            }                                                                              \
        }                                                                                  \
    }

__kernel __attribute__((reqd_work_group_size(LX, LY, 1)))
void blur_adjoint_cpu(__global const float *restrict src, __global float *restrict dst,
                      __global const float *restrict psfs, __global const int *restrict goff,
                      __global const int4 *restrict gids, __global const float *restrict gw,
                      __global const int *restrict agoff, __global const int4 *restrict agids,
                      __global const int2 *restrict arows, __global const int *restrict asup,
                      __global const int *restrict aext,
                      const int H, const int W, const int NCH, const int NBY)
{
    const int cx = get_global_id(0), by = get_global_id(1);
    if (cx >= NCH || by >= NBY) return;
    const int x0 = cx * CW, Y0 = by * ROWS_COL, Y1 = min(Y0 + ROWS_COL, H);
    const size_t plane = (size_t)H * W;
    float16 Vr[RING][CHANNELS][NV], Wr[RING][4][NV];
    const int a0 = agoff[by * NCH + cx], a1 = agoff[by * NCH + cx + 1];
    /* several groups: each adds its share, over the rows its PSFs reach only */
    const bool accumulate = a1 - a0 != 1;

    if (accumulate) {
        for (int y = Y0; y < Y1; ++y)
            for (int c = 0; c < CHANNELS; ++c)
                store_chunk(dst + c * plane + (size_t)y * W, (float16)(0.0f), x0, W);
    }
    for (int a = a0; a < a1; ++a) {
        const int4 e = agids[a];
        const int4 ec = max(e, (int4)(0));           /* empty slots (-1) get weight 0 */
        __global const float *p0 = psfs + ec.s0 * KK, *p1 = psfs + ec.s1 * KK;
        __global const float *p2 = psfs + ec.s2 * KK, *p3 = psfs + ec.s3 * KK;
        /* input rows where the group's PSFs have weight in this column's reach */
        const int rlo = max(arows[a].x, 0), rhi = min(arows[a].y, H - 1);
        const int sg = asup[a];                      /* taps beyond sg are zero */
        __global const int *ea = aext + a * K;       /* per kernel row, taps beyond are zero */
        int next = rlo;                              /* next input row to bring into the ring */
        for (int y0 = Y0; y0 < Y1; y0 += ROWS_ADJ) {
            const int ylo = max(y0 - sg, rlo), yhi = min(y0 + ROWS_ADJ - 1 + sg, rhi);
            if (accumulate && ylo > yhi) continue;   /* nothing of this group reaches here */
            for (next = max(next, ylo); next <= yhi; ++next) {
                const int slot = next & (RING - 1);
                #pragma unroll
                for (int c = 0; c < CHANNELS; ++c)
                    load_segment(Vr[slot][c], src + c * plane + (size_t)next * W, x0, W);
                weight_segment(Wr[slot], e, next, cx, NCH, goff, gids, gw);
            }
            float16 acc[ROWS_ADJ][CHANNELS];
            #pragma unroll
            for (int i = 0; i < ROWS_ADJ; ++i)
                #pragma unroll
                for (int c = 0; c < CHANNELS; ++c) acc[i][c] = (float16)(0.0f);
            /* input row j of the block's reach (yr = y0 - RADIUS + j) feeds output rows
             * i in [max(0, j - 2R), min(RA - 1, j)]: the first and last RA - 1 rows are
             * written out with those bounds as constants (a loop over them is too big for
             * LLVM to unroll at larger radii, and the accumulators would then spill); the
             * middle rows feed all RA rows. */
#if ROWS_ADJ >= 2
            ADJ_ROW(0, 0, 0)
#endif
#if ROWS_ADJ >= 3
            ADJ_ROW(1, 0, 1)
#endif
#if ROWS_ADJ >= 4
            ADJ_ROW(2, 0, 2)
#endif
            for (int j = ROWS_ADJ - 1; j <= 2 * RADIUS; ++j) ADJ_ROW(j, 0, ROWS_ADJ - 1)
#if ROWS_ADJ >= 2
            ADJ_ROW(2 * RADIUS + 1, 1, ROWS_ADJ - 1)
#endif
#if ROWS_ADJ >= 3
            ADJ_ROW(2 * RADIUS + 2, 2, ROWS_ADJ - 1)
#endif
#if ROWS_ADJ >= 4
            ADJ_ROW(2 * RADIUS + 3, 3, ROWS_ADJ - 1)
#endif
            for (int i = 0; i < ROWS_ADJ && y0 + i < Y1; ++i) {
                #pragma unroll
                for (int c = 0; c < CHANNELS; ++c) {
                    __global float *d = dst + c * plane + (size_t)(y0 + i) * W;
                    if (accumulate) acc[i][c] += load_chunk(d, x0, W);  /* this item owns d */
                    store_chunk(d, acc[i][c], x0, W);
                }
            }
        }
    }
}
#endif /* VARIANT_CPU */
