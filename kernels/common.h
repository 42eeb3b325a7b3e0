/* common.h - helpers shared by every OpenCL program (included with #include "common.h"; the
 * runtime passes -I <kernels dir>, and PyOpenCL's disk cache hashes this header too).
 * Images are row-major H x W float32 planes, linear light, unless a kernel says otherwise.
 *
 * Reductions run in two stages: each work-group sums its share with wg_sum4 and writes it with
 * store_partials as partials[k * n_groups + group] (quantity k < 4, groups numbered row-major);
 * solver.cl:reduce_partials then sums each quantity over the groups.
 */
#ifndef RTDEFOCUS_COMMON_H
#define RTDEFOCUS_COMMON_H

#define IDX(y, x, w) ((y) * (w) + (x))

/* Tree sum of up to 4 quantities over the work-group of n work-items (n a power of two, the
 * exact work-group size; 1-D or 2-D, items numbered row-major). scratch: n float4 of __local
 * memory. Called by every work-item; the total is valid in work-item 0. */
inline float4 wg_sum4(__local float4 *scratch, const float4 v, const int n)
{
    const int lid = get_local_id(1) * get_local_size(0) + get_local_id(0);
    scratch[lid] = v;
    barrier(CLK_LOCAL_MEM_FENCE);
    for (int s = n / 2; s > 0; s >>= 1) {
        if (lid < s) scratch[lid] += scratch[lid + s];
        barrier(CLK_LOCAL_MEM_FENCE);
    }
    return scratch[0];
}

/* Work-item 0 writes its group's totals of nq (1..4) quantities: partials[k * n_groups + g]. */
inline void store_partials(__global float *partials, const float4 total, const int nq)
{
    if (get_local_id(0) == 0 && get_local_id(1) == 0) {
        const int ng = get_num_groups(0) * get_num_groups(1);
        const int g = get_group_id(1) * get_num_groups(0) + get_group_id(0);
        partials[g] = total.x;
        if (nq > 1) partials[ng + g] = total.y;
        if (nq > 2) partials[2 * ng + g] = total.z;
        if (nq > 3) partials[3 * ng + g] = total.w;
    }
}

/* Sum of the 16 lanes of a vector, by halves (the order both CPU kernel shapes rely on). */
inline float hsum16(const float16 v)
{
    const float8 a = v.lo + v.hi;
    const float4 b = a.lo + a.hi;
    const float2 c = b.lo + b.hi;
    return c.x + c.y;
}

#endif
