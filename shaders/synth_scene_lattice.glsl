// Scene "lattice": a 3D lattice of thin bars around a striped, bumpy sphere, with one small
// orbiting light; the camera circles the sphere.

void scene_camera(float t, out vec3 ro, out vec3 ta) {
    float a = 0.45 * t + 0.3;
    ro = vec3(3.2 * sin(a), 0.6 + 0.3 * sin(0.8 * t), -3.2 * cos(a));
    ta = vec3(0.0, 0.1, 0.0);
}

float scene_map(vec3 p, float t, out int mat) {
    float ground = p.y + 1.2;
    float ball = length(p) - 0.9 + 0.02 * sin(18.0 * p.x) * sin(18.0 * p.y) * sin(18.0 * p.z);
    vec3 q = mod(p + 0.4, 0.8) - 0.4;
    float bars = min(min(length(q.xy), length(q.yz)), length(q.xz)) - 0.012;
    bars = max(bars, length(p) - 2.4);
    bars = max(bars, 1.0 - length(p));
    float d = ground;
    mat = 0;
    if (ball < d) { d = ball; mat = 1; }
    if (bars < d) { d = bars; mat = 2; }
    return d;
}

void scene_material(vec3 p, vec3 n, int mat, float t, out vec3 albedo, out vec3 emission) {
    emission = vec3(0.0);
    if (mat == 0) {
        float rings = step(0.5, fract(length(p.xz) * 6.0));
        albedo = mix(vec3(0.2, 0.22, 0.25), vec3(0.6, 0.62, 0.6), rings);
        albedo *= 0.75 + 0.5 * value_noise(p.xz * 30.0);
    } else if (mat == 1) {
        float stripes = step(0.5, fract(atan(p.z, p.x) * 7.0 / PI + p.y * 3.0));
        albedo = mix(vec3(0.85, 0.8, 0.7), vec3(0.6, 0.1, 0.12), stripes);
    } else {
        albedo = vec3(0.9, 0.85, 0.4);
    }
}

int scene_light_count() { return 2; }

vec4 scene_light(int i, float t, out vec3 colour) {
    if (i == 0) {
        colour = vec3(3.5, 2.8, 1.5);
        float a = 1.7 * t;
        return vec4(1.5 * cos(a), 0.3 + 0.4 * sin(0.9 * t), 1.5 * sin(a), 0.03);
    }
    colour = vec3(0.8, 1.8, 3.2);
    return vec4(-1.2, -0.9, 1.1, 0.025);
}

void scene_sky(out vec3 c0, out vec3 c1, out vec3 sun_dir, out vec3 sun_radiance,
               out float sun_radius) {
    c0 = vec3(0.30, 0.33, 0.40);
    c1 = vec3(0.25, 0.30, 0.40);
    sun_dir = normalize(vec3(0.4, 0.7, -0.3));
    sun_radius = 0.22;
    sun_radiance = vec3(21.0, 19.5, 17.0);
}
