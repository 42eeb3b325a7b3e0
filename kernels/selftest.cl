/* selftest.cl - the smallest program: out = a * x + y (SAXPY), used by `rtdefocus info`
 * and the runtime tests to prove the device builds and runs code from kernels/.
 * x, y, out: float32[n]; global size: n. SCALE is a -D constant multiplying a. */
#include "common.h"
#ifndef SCALE
#define SCALE 1.0f
#endif
__kernel void saxpy(const float a, __global const float *x, __global const float *y,
                    __global float *out, const int n)
{
    const int i = get_global_id(0);
    if (i < n) out[i] = SCALE * a * x[i] + y[i];
}
