// GL sharing (cl_khr_gl_sharing): the GL warp's framebuffer, shared as an OpenCL image, into
// the solver's uint8 (H, W, 3) codes buffer without a trip through the host.
// NumPy twin: rtdefocus.cl.glshare.codes_from_rgba (= rtdefocus.gl.runtime.read_rgb's flip).
//
// The image is RGBA8 (CL_RGBA, CL_UNORM_INT8) with GL's origin at the bottom-left: output row
// y reads image row H - 1 - y; alpha is dropped. read_imagef returns c / 255 for a code c, and
// c / 255 * 255 rounds back to c exactly, so the codes are bit-identical to a read-back.

__constant sampler_t NEAREST = CLK_NORMALIZED_COORDS_FALSE | CLK_ADDRESS_NONE | CLK_FILTER_NEAREST;

__kernel void rgba_image_to_codes(read_only image2d_t img, __global uchar *codes,
                                  const int w, const int h)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= w || y >= h) return;
    const float4 v = read_imagef(img, NEAREST, (int2)(x, h - 1 - y));
    const uchar4 c = convert_uchar4_sat_rte(v * 255.0f);
    __global uchar *o = codes + 3 * ((size_t)y * w + x);
    o[0] = c.x; o[1] = c.y; o[2] = c.z;
}
