#version 330 core
// Pre-rendered text (RGBA, top row first) drawn at 1:1 pixels with alpha blending.
uniform sampler2D u_tex;
uniform vec4 u_tint;
in vec2 v_uv;
out vec4 f_color;
void main() {
    vec4 c = texture(u_tex, vec2(v_uv.x, v_uv.y));
    f_color = vec4(c.rgb * u_tint.rgb, c.a * u_tint.a);
}
