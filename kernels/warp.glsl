// warp.glsl — geometric warp + stitch (docs/internals.md, "The warp"; reference: rtdefocus/reference/warp.py).
//
// Per projector pixel (x, y): plane p from the plane layout (PlaneLayout.label: the plane the
// pixel is least outside of, ties to the higher index; with two planes p = 0 where
// fold·(x, y, 1) < 0, else 1), read from a label texture the size of the projector frame that
// Python fills with exactly those labels (so shader and reference agree on every pixel, and a
// fragment pays one texel fetch whatever the number of planes); camera point
// H_cam_from_proj[p]·(x, y, 1), plus the plane's smooth residual at the pixel (u_offset, zeros
// when the calibration has none); input pixel u = (xc − x0 + 0.5)·W/w − 0.5 (same for v);
// bilinear, trilinear when minified, black outside (sampler: CLAMP_TO_BORDER, border 0).
//
// Python (rtdefocus/gl/warp.py) folds the whole chain into one 3×3 matrix per plane, in float64:
//   u_st_from_frag[p] = A · H[p] · B, with B: gl_FragCoord (fx, fy) -> projector pixel
//   (x, y) = (fx − 0.5, Hp − 0.5 − fy) (GL's origin is bottom-left, pixel centres at +0.5), and
//   A: camera pixel -> normalised texture coordinate s = (xc − x0 + 0.5)/w = (u + 0.5)/W, whose
//   texel centres (i + 0.5)/W are the input's pixel centres, so GL_LINEAR is exactly the
//   bilinear of the reference. u_labels holds the plane of each fragment, row 0 at the bottom
//   like gl_FragCoord. u_offset (RG32F, the projector frame's size, rows bottom-up) holds each
//   pixel's residual already in (s, t) units (camera px / (w, h)), added after the divide; the
//   lod stays the homography's (the residual's slope is a few px over hundreds). MAX_PLANES comes from Python (a -D define prepended at build time) so
//   the matrix array matches planar.MAX_PLANES.
// Texture row 0 is the input's top row (uploaded as is), so t grows downwards like v.
// Output: colour in the input's encoding; read back top row first by gl.runtime.read_rgb.
// Draw: one full-screen triangle, 3 vertices, no attributes.

#if defined VERTEX_SHADER

void main() {
    // (-1,-1), (3,-1), (-1,3): covers the viewport with one triangle, no diagonal seam.
    vec2 p = vec2(gl_VertexID == 1 ? 3.0 : -1.0, gl_VertexID == 2 ? 3.0 : -1.0);
    gl_Position = vec4(p, 0.0, 1.0);
}

#elif defined FRAGMENT_SHADER

uniform sampler2D u_image;        // input, RGB8, mip levels built on the CPU when minified
uniform usampler2D u_labels;      // plane of each projector pixel (R8UI, no filtering)
uniform sampler2D u_offset;       // residual of each projector pixel in (s, t) units (RG32F)
uniform mat3 u_st_from_frag[MAX_PLANES];    // per plane: (fx, fy, 1) -> homogeneous (s, t, 1)
uniform vec2 u_image_size;        // (W, H) of level 0, texels per unit of s, t

out vec4 f_color;

void main() {
    vec3 frag = vec3(gl_FragCoord.xy, 1.0);
    uint plane = texelFetch(u_labels, ivec2(gl_FragCoord.xy), 0).r;
    mat3 M = u_st_from_frag[min(plane, uint(MAX_PLANES - 1))];
    vec3 q = M * frag;
    if (!(q.z > 0.0)) {                       // beyond the homography's horizon: no surface
        f_color = vec4(0.0, 0.0, 0.0, 1.0);
        return;
    }
    vec2 st = q.xy / q.z;
    vec2 st_off = texelFetch(u_offset, ivec2(gl_FragCoord.xy), 0).xy;
    // Level of detail from the analytic Jacobian of this plane's mapping (M[c] is column c):
    // d(s,t)/dfx = (M[0].xy − st·M[0].z)/q.z. Screen-space derivatives would jump at the fold
    // and pick a wrong level in the 2×2 quads straddling it (a visible seam).
    vec2 d_dx = (M[0].xy - st * M[0].z) / q.z * u_image_size;
    vec2 d_dy = (M[1].xy - st * M[1].z) / q.z * u_image_size;
    float lod = log2(max(length(d_dx), length(d_dy)));   // the GL spec's rho, in input texels
    f_color = vec4(textureLod(u_image, st + st_off, lod).rgb, 1.0);
}

#endif
