#version 330 core
// One video frame drawn at exactly 1:1 pixels: each fragment fetches its own texel, so no
// filtering or scaling can touch the stimulus. Frames are stored top row first.
uniform sampler2DArray u_frames;
uniform int u_layer;
uniform ivec2 u_origin;   // top-left of the video in window pixels
uniform int u_win_h;      // window height in pixels (gl_FragCoord counts from the bottom)
out vec4 f_color;
void main() {
    ivec2 frag = ivec2(floor(gl_FragCoord.xy));
    ivec2 texel = ivec2(frag.x - u_origin.x, (u_win_h - 1 - frag.y) - u_origin.y);
    f_color = vec4(texelFetch(u_frames, ivec3(texel, u_layer), 0).rgb, 1.0);
}
