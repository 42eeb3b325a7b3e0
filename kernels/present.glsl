// present.glsl — show one RGB8 frame in the projector window (rtdefocus/gl/window.py).
//
// The frame is uploaded as is: texture row 0 is the image's top row, so t = 1 − (the
// viewport's y from the bottom). The viewport is the frame's letterbox inside the window; when
// the frame and the viewport have the same size the sampler is GL_NEAREST and every projector
// pixel gets exactly its own value (the compensation is computed per projector pixel).
// Draw: one full-screen triangle, 3 vertices, no attributes.

#if defined VERTEX_SHADER

out vec2 v_st;

void main() {
    // (-1,-1), (3,-1), (-1,3): covers the viewport with one triangle, no diagonal seam.
    vec2 p = vec2(gl_VertexID == 1 ? 3.0 : -1.0, gl_VertexID == 2 ? 3.0 : -1.0);
    v_st = vec2(0.5 * p.x + 0.5, 0.5 - 0.5 * p.y);
    gl_Position = vec4(p, 0.0, 1.0);
}

#elif defined FRAGMENT_SHADER

uniform sampler2D u_frame;   // RGB8, (W, H) of the frame

in vec2 v_st;
out vec4 f_color;

void main() {
    f_color = vec4(texture(u_frame, v_st).rgb, 1.0);
}

#endif
