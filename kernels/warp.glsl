// warp.glsl — geometric warp + stitch (docs/internals.md, "The warp"; reference: rtdefocus/reference/warp.py).
//
// Per projector pixel (x, y): plane p from the plane layout (PlaneLayout.label: the plane the
// pixel is least outside of, ties to the higher index; with two planes p = 0 where
// fold·(x, y, 1) < 0, else 1); camera point H_cam_from_proj[p]·(x, y, 1); input pixel u = (xc − x0 + 0.5)·W/w − 0.5 (same for v);
// bilinear, trilinear when minified, black outside (sampler: CLAMP_TO_BORDER, border 0).
//
// Python (rtdefocus/gl/warp.py) folds the whole chain into one 3×3 matrix per plane, in float64:
//   u_st_from_frag[p] = A · H[p] · B, with B: gl_FragCoord (fx, fy) -> projector pixel
//   (x, y) = (fx − 0.5, Hp − 0.5 − fy) (GL's origin is bottom-left, pixel centres at +0.5), and
//   A: camera pixel -> normalised texture coordinate s = (xc − x0 + 0.5)/w = (u + 0.5)/W, whose
//   texel centres (i + 0.5)/W are the input's pixel centres, so GL_LINEAR is exactly the
//   bilinear of the reference. u_folds_frag[j] = fold_j·B are the fold lines in the same
//   coordinates; u_sign[p * MAX_FOLDS + j] is +1 / -1 where plane p lies on fold j's positive /
//   negative side, 0 where fold j does not bound plane p. MAX_PLANES and MAX_FOLDS come from
//   Python (-D defines prepended at build time) so the arrays match calib.planar.MAX_PLANES.
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
uniform mat3 u_st_from_frag[MAX_PLANES];    // per plane: (fx, fy, 1) -> homogeneous (s, t, 1)
uniform vec3 u_folds_frag[MAX_FOLDS];       // fold lines in fragment coordinates
uniform float u_sign[MAX_PLANES * MAX_FOLDS];
uniform int u_n_planes;
uniform int u_n_folds;
uniform vec2 u_image_size;        // (W, H) of level 0, texels per unit of s, t

out vec4 f_color;

int plane_of(vec3 frag) {
    float side[MAX_FOLDS];
    for (int j = 0; j < u_n_folds; ++j) side[j] = dot(u_folds_frag[j], frag);
    int best = 0;
    float best_out = 0.0;
    for (int p = 0; p < u_n_planes; ++p) {
        float outside = -3.0e38;          // how far outside plane p (<= 0 inside)
        for (int j = 0; j < u_n_folds; ++j) {
            float s = u_sign[p * MAX_FOLDS + j];
            if (s != 0.0) outside = max(outside, -s * side[j]);
        }
        if (p == 0 || outside <= best_out) {
            best = p;
            best_out = outside;
        }
    }
    return best;
}

void main() {
    vec3 frag = vec3(gl_FragCoord.xy, 1.0);
    mat3 M = u_st_from_frag[plane_of(frag)];
    vec3 q = M * frag;
    if (!(q.z > 0.0)) {                       // beyond the homography's horizon: no surface
        f_color = vec4(0.0, 0.0, 0.0, 1.0);
        return;
    }
    vec2 st = q.xy / q.z;
    // Level of detail from the analytic Jacobian of this plane's mapping (M[c] is column c):
    // d(s,t)/dfx = (M[0].xy − st·M[0].z)/q.z. Screen-space derivatives would jump at the fold
    // and pick a wrong level in the 2×2 quads straddling it (a visible seam).
    vec2 d_dx = (M[0].xy - st * M[0].z) / q.z * u_image_size;
    vec2 d_dy = (M[1].xy - st * M[1].z) / q.z * u_image_size;
    float lod = log2(max(length(d_dx), length(d_dy)));   // the GL spec's rho, in input texels
    f_color = vec4(textureLod(u_image, st, lod).rgb, 1.0);
}

#endif
