/* common.h - helpers shared by every OpenCL program (included with #include "common.h").
 * Images are row-major H x W float32 planes, linear light, unless a kernel says otherwise. */
#ifndef RTDEFOCUS_COMMON_H
#define RTDEFOCUS_COMMON_H
#define IDX(y, x, w) ((y) * (w) + (x))
#endif
