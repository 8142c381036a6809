#version 330 core
// A flat colour (background, the mid-grey blank, slider track and marker, buttons).
uniform vec4 u_color;
out vec4 f_color;
void main() {
    f_color = u_color;
}
