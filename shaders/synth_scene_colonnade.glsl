// Scene "colonnade": a finely chequered floor with thin grid lines, rows of thin pillars and
// a wire strung between them, two small bright lights; the camera flies forward and pans.

void scene_camera(float t, out vec3 ro, out vec3 ta) {
    ro = vec3(0.35 * sin(0.7 * t), 0.55 + 0.05 * sin(1.3 * t), 1.2 * t);
    ta = ro + vec3(0.6 * sin(0.5 * t + 0.4), -0.12, 1.0);
}

float scene_map(vec3 p, float t, out int mat) {
    float floor_d = p.y;
    // pillars every 1.0 in x and z (|x| >= 0.5 only, so the camera's lane stays free)
    vec3 q = p;
    q.xz = mod(q.xz + 0.5, 1.0) - 0.5;
    float pillar = length(q.xz) - 0.035;
    pillar = max(pillar, p.y - 1.4);
    pillar = max(pillar, 0.45 - abs(p.x));
    // a thin wire at the top of every row of pillars
    vec2 w = vec2(mod(p.x + 0.5, 1.0) - 0.5, p.y - 1.35);
    float wire = max(length(w) - 0.008, 0.45 - abs(p.x));
    float d = min(pillar, wire);
    mat = 1;
    if (floor_d < d) {
        d = floor_d;
        mat = 0;
    }
    return d;
}

void scene_material(vec3 p, vec3 n, int mat, float t, out vec3 albedo, out vec3 emission) {
    emission = vec3(0.0);
    if (mat == 0) {
        vec2 c = floor(p.xz * 8.0);
        float checker = mod(c.x + c.y, 2.0);
        vec2 g = abs(fract(p.xz * 2.0) - 0.5);
        float line = step(0.47, max(g.x, g.y));
        float grain = value_noise(p.xz * 40.0);
        albedo = mix(vec3(0.18, 0.17, 0.16), vec3(0.75, 0.72, 0.66), checker);
        albedo *= 0.8 + 0.4 * grain;
        albedo = mix(albedo, vec3(0.9, 0.25, 0.1), line);
    } else {
        float band = step(0.5, fract(p.y * 12.0));
        albedo = mix(vec3(0.8), vec3(0.1, 0.2, 0.5), band);
    }
}

int scene_light_count() { return 2; }

vec4 scene_light(int i, float t, out vec3 colour) {
    if (i == 0) {
        colour = vec3(3.0, 2.2, 1.2);
        return vec4(0.25 * sin(1.1 * t), 0.9, 1.2 * t + 2.0, 0.025);
    }
    colour = vec3(1.0, 2.0, 3.5);
    return vec4(-0.3, 0.35 + 0.2 * sin(2.0 * t), 1.2 * t + 3.5, 0.02);
}

void scene_sky(out vec3 c0, out vec3 c1, out vec3 sun_dir, out vec3 sun_radiance,
               out float sun_radius) {
    c0 = vec3(0.35, 0.40, 0.50);
    c1 = vec3(0.20, 0.30, 0.45);
    sun_dir = normalize(vec3(-0.5, 0.45, 0.6));
    sun_radius = 0.22;
    sun_radiance = vec3(21.0, 19.0, 16.0);
}
