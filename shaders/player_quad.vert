#version 330 core
// A screen-aligned rectangle given in window pixels (origin top-left).
uniform vec4 u_rect;      // x, y, width, height in pixels
uniform vec2 u_viewport;  // window width, height in pixels
in vec2 in_corner;        // (0,0) .. (1,1)
out vec2 v_uv;
void main() {
    vec2 px = u_rect.xy + in_corner * u_rect.zw;
    vec2 ndc = vec2(px.x / u_viewport.x * 2.0 - 1.0, 1.0 - px.y / u_viewport.y * 2.0);
    v_uv = in_corner;
    gl_Position = vec4(ndc, 0.0, 1.0);
}
