#version 330 core
// One video frame at exactly 1:1 pixels: the quad has the frame's size at whole-pixel
// coordinates and nearest filtering samples each texel at its centre, so no filtering or
// scaling can touch the stimulus. Frames are stored top row first.
uniform sampler2D u_tex;
in vec2 v_uv;
out vec4 f_color;
void main() {
    f_color = vec4(texture(u_tex, v_uv).rgb, 1.0);
}
