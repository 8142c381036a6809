#version 330 core
// Shared part of the synthetic-scene renderer (study_app.synth). A scene file
// (synth_scene_*.glsl) is appended to this text; it defines the functions declared under
// "scene interface" below.
//
// Why the shading is built the way it is: every geometry sample has a lighting integral whose
// expectation is known in closed form (a linear sky, a small sun disc, a few point lights
// picked at random). The reference uses that expectation, so it is noise-free with 16
// anti-aliasing samples, and the Monte Carlo images estimate the same integral with random
// samples, so their error against the reference is pure sampling noise (fireflies from the
// small, very bright sun included) and falls as the sample count grows.
//
// Passes (u_pass):
//   0: out0 = reference colour (u_aa anti-aliasing samples, expected lighting);
//      when u_mc != 0, out1..out6 = Monte Carlo estimates at 2, 4, 8, 16, 64, 256 samples
//      per pixel (prefixes of one sample sequence, like a progressive path tracer);
//      out7 = albedo averaged over the same anti-aliasing samples (the denoiser's guide).
//   1: one sample at pixel centre + u_jitter (pixels): out0 = expected colour,
//      out1 = (motion x, motion y, depth, hit), out2 = (normal, 0), out3 = (albedo, 0).
// Motion is in pixels, image axes (x right, y down): where this surface point was at
// u_time_prev minus where it is now.

uniform vec2 u_res;
uniform float u_time;
uniform float u_time_prev;
uniform int u_pass;
uniform int u_aa;
uniform int u_mc;
uniform vec2 u_jitter;
uniform uint u_seed;
uniform uint u_frame;

layout(location = 0) out vec4 out0;
layout(location = 1) out vec4 out1;
layout(location = 2) out vec4 out2;
layout(location = 3) out vec4 out3;
layout(location = 4) out vec4 out4;
layout(location = 5) out vec4 out5;
layout(location = 6) out vec4 out6;
layout(location = 7) out vec4 out7;

const float PI = 3.14159265358979;
const float FOCAL = 1.6;
const float T_MAX = 40.0;
const int MAX_STEPS = 72;
const int MAX_LIGHTS = 4;

// ---- scene interface (defined by the scene file) -------------------------------------
void scene_camera(float t, out vec3 ro, out vec3 ta);
float scene_map(vec3 p, float t, out int mat);
void scene_material(vec3 p, vec3 n, int mat, float t, out vec3 albedo, out vec3 emission);
int scene_light_count();
vec4 scene_light(int i, float t, out vec3 colour);  // xyz = position, w = radius
void scene_sky(out vec3 c0, out vec3 c1, out vec3 sun_dir, out vec3 sun_radiance,
               out float sun_radius);

// ---- hashing and random numbers ------------------------------------------------------
uint pcg(uint v) {
    uint state = v * 747796405u + 2891336453u;
    uint word = ((state >> ((state >> 28u) + 4u)) ^ state) * 277803737u;
    return (word >> 22u) ^ word;
}

float hash12(vec2 p) {
    uvec2 q = uvec2(ivec2(floor(p))) * uvec2(1597334673u, 3812015801u);
    uint n = pcg(q.x ^ q.y);
    return float(n) * (1.0 / 4294967296.0);
}

float value_noise(vec2 p) {
    vec2 i = floor(p);
    vec2 f = fract(p);
    vec2 u = f * f * (3.0 - 2.0 * f);
    float a = hash12(i);
    float b = hash12(i + vec2(1.0, 0.0));
    float c = hash12(i + vec2(0.0, 1.0));
    float d = hash12(i + vec2(1.0, 1.0));
    return mix(mix(a, b, u.x), mix(c, d, u.x), u.y);
}

uint rng_state;

void rng_init(uvec2 pixel, uint stream) {
    rng_state = pcg(pcg(pcg(pixel.x + 0x9E3779B9u * u_seed) ^ pixel.y * 0x85EBCA6Bu)
                    ^ (u_frame * 0xC2B2AE35u) ^ (stream * 0x27D4EB2Fu));
}

float rand01() {
    rng_state = pcg(rng_state);
    return float(rng_state) * (1.0 / 4294967296.0);
}

// ---- camera --------------------------------------------------------------------------
void camera_basis(float t, out vec3 ro, out vec3 fw, out vec3 rt, out vec3 up) {
    vec3 ta;
    scene_camera(t, ro, ta);
    fw = normalize(ta - ro);
    rt = normalize(cross(fw, vec3(0.0, 1.0, 0.0)));
    up = cross(rt, fw);
}

vec2 project(vec3 p, float t) {
    vec3 ro, fw, rt, up;
    camera_basis(t, ro, fw, rt, up);
    vec3 v = p - ro;
    float z = max(dot(v, fw), 1e-4);
    vec2 uv = vec2(dot(v, rt), dot(v, up)) * FOCAL / z;
    return uv * (0.5 * u_res.y) + 0.5 * u_res;
}

// ---- geometry ------------------------------------------------------------------------
struct Geom {
    bool hit;
    vec3 ro;
    vec3 rd;
    vec3 p;
    vec3 n;
    float depth;
    vec3 albedo;
    vec3 emission;   // surface emission, or what a ray that leaves the scene sees
    float sun_vis;   // 1 when the sun is not blocked at p
};

float map(vec3 p) {
    int mat;
    return scene_map(p, u_time, mat);
}

vec3 sdf_normal(vec3 p) {
    const vec2 k = vec2(1.0, -1.0);
    const float h = 0.0008;
    return normalize(k.xyy * map(p + k.xyy * h) + k.yyx * map(p + k.yyx * h)
                     + k.yxy * map(p + k.yxy * h) + k.xxx * map(p + k.xxx * h));
}

float light_hit(vec3 ro, vec3 rd, vec4 sphere) {
    vec3 oc = ro - sphere.xyz;
    float b = dot(oc, rd);
    float c = dot(oc, oc) - sphere.w * sphere.w;
    float h = b * b - c;
    if (h < 0.0) return -1.0;
    return -b - sqrt(h);
}

float shadow(vec3 p, vec3 dir) {
    float t = 0.02;
    for (int i = 0; i < 40; i++) {
        float d = map(p + dir * t);
        if (d < 0.0005 * t) return 0.0;
        t += d;
        if (t > 20.0) break;
    }
    return 1.0;
}

vec3 sky_radiance(vec3 d) {
    vec3 c0, c1, s, ls;
    float sr;
    scene_sky(c0, c1, s, ls, sr);
    vec3 col = c0 + c1 * d.y;
    if (dot(d, s) > cos(sr)) col += ls;
    return col;
}

Geom trace(vec2 frag) {
    Geom g;
    vec3 fw, rt, up;
    camera_basis(u_time, g.ro, fw, rt, up);
    vec2 uv = (frag - 0.5 * u_res) / (0.5 * u_res.y);
    g.rd = normalize(uv.x * rt + uv.y * up + FOCAL * fw);
    float t = 0.01;
    g.hit = false;
    int mat = 0;
    for (int i = 0; i < MAX_STEPS; i++) {
        float d = scene_map(g.ro + g.rd * t, u_time, mat);
        if (d < 0.0005 * t) {
            g.hit = true;
            break;
        }
        t += d;
        if (t > T_MAX) break;
    }
    // small bright lights are analytic spheres in front of (or instead of) the surface
    int nl = scene_light_count();
    float tl = g.hit ? t : 1e9;
    vec3 light_col = vec3(0.0);
    bool saw_light = false;
    for (int i = 0; i < MAX_LIGHTS; i++) {
        if (i >= nl) break;
        vec3 c;
        vec4 sph = scene_light(i, u_time, c);
        float th = light_hit(g.ro, g.rd, sph);
        if (th > 0.0 && th < tl) {
            tl = th;
            light_col = c * 6.0;
            saw_light = true;
        }
    }
    g.albedo = vec3(0.0);
    g.n = -g.rd;
    g.sun_vis = 0.0;
    if (saw_light) {
        g.hit = false;
        g.p = g.ro + g.rd * tl;
        g.depth = tl;
        g.emission = light_col;
        return g;
    }
    if (!g.hit) {
        g.p = g.ro + g.rd * 1000.0;
        g.depth = T_MAX;
        g.emission = sky_radiance(g.rd);
        return g;
    }
    g.p = g.ro + g.rd * t;
    g.depth = t;
    g.n = sdf_normal(g.p);
    scene_material(g.p, g.n, mat, u_time, g.albedo, g.emission);
    vec3 c0, c1, s, ls;
    float sr;
    scene_sky(c0, c1, s, ls, sr);
    g.sun_vis = dot(g.n, s) > sin(sr) ? shadow(g.p + g.n * 0.002, s) : 0.0;
    return g;
}

// ---- lighting: closed-form expectation and its Monte Carlo estimator -----------------
vec3 point_light(vec3 p, vec3 n, int i) {
    vec3 c;
    vec4 sph = scene_light(i, u_time, c);
    vec3 l = sph.xyz - p;
    float d2 = dot(l, l);
    return c * max(dot(n, l * inversesqrt(d2)), 0.0) / (1.0 + d2);
}

vec3 expected_colour(Geom g) {
    if (!g.hit) return g.emission;
    vec3 c0, c1, s, ls;
    float sr;
    scene_sky(c0, c1, s, ls, sr);
    // cosine-weighted hemisphere average of c0 + c1 * w.y is c0 + c1 * (2/3) n.y; the sun
    // disc (a spherical cap of angular radius sr, fully above the horizon of n) adds
    // ls * sin^2(sr) * (n . s).
    vec3 e = c0 + c1 * (2.0 / 3.0) * g.n.y;
    float ns = dot(g.n, s);
    if (ns > sin(sr)) e += ls * g.sun_vis * sin(sr) * sin(sr) * ns;
    int nl = scene_light_count();
    for (int i = 0; i < MAX_LIGHTS; i++) {
        if (i >= nl) break;
        e += point_light(g.p, g.n, i);
    }
    return g.emission + g.albedo * e;
}

vec3 estimate_colour(Geom g) {
    if (!g.hit) return g.emission;
    vec3 c0, c1, s, ls;
    float sr;
    scene_sky(c0, c1, s, ls, sr);
    // one cosine-weighted direction for sky and sun
    float u1 = rand01();
    float u2 = rand01();
    float r = sqrt(u1);
    float phi = 2.0 * PI * u2;
    vec3 a = abs(g.n.x) > 0.9 ? vec3(0.0, 1.0, 0.0) : vec3(1.0, 0.0, 0.0);
    vec3 tx = normalize(cross(a, g.n));
    vec3 ty = cross(g.n, tx);
    vec3 w = normalize(r * cos(phi) * tx + r * sin(phi) * ty + sqrt(max(1.0 - u1, 0.0)) * g.n);
    vec3 e = c0 + c1 * w.y;
    if (dot(g.n, s) > sin(sr) && dot(w, s) > cos(sr)) e += ls * g.sun_vis;
    // one point light picked uniformly, weighted by the count
    int nl = scene_light_count();
    if (nl > 0) {
        int i = min(int(rand01() * float(nl)), nl - 1);
        e += float(nl) * point_light(g.p, g.n, i);
    }
    return g.emission + g.albedo * e;
}

// 16 anti-aliasing positions: a 4x4 grid visited so that the first 2, 4 and 8 are spread
// over the pixel, each jittered inside its cell by a per-pixel hash (same in every frame).
const ivec2 AA_CELLS[16] = ivec2[16](
    ivec2(0, 0), ivec2(2, 2), ivec2(2, 0), ivec2(0, 2), ivec2(1, 1), ivec2(3, 3),
    ivec2(3, 1), ivec2(1, 3), ivec2(1, 0), ivec2(3, 2), ivec2(3, 0), ivec2(1, 2),
    ivec2(0, 1), ivec2(2, 3), ivec2(2, 1), ivec2(0, 3));

vec2 aa_offset(uvec2 pixel, int k) {
    uint h = pcg(pcg(pixel.x * 73856093u ^ pixel.y * 19349663u) + uint(k) * 83492791u);
    vec2 j = vec2(float(h & 0xFFFFu), float(h >> 16u)) * (1.0 / 65536.0);
    return (vec2(AA_CELLS[k]) + j) * 0.25;
}

void main() {
    vec2 base = floor(gl_FragCoord.xy);
    uvec2 pixel = uvec2(base);
    out0 = out1 = out2 = out3 = out4 = out5 = out6 = out7 = vec4(0.0);
    if (u_pass == 1) {
        Geom g = trace(base + 0.5 + u_jitter);
        vec2 prev = project(g.p, u_time_prev);
        vec2 now = base + 0.5 + u_jitter;
        vec2 motion = vec2(prev.x - now.x, -(prev.y - now.y));
        out0 = vec4(expected_colour(g), 1.0);
        out1 = vec4(motion, g.depth, g.hit ? 1.0 : 0.0);
        out2 = vec4(g.n, 0.0);
        out3 = vec4(g.albedo, 0.0);
        return;
    }
    int aa = clamp(u_aa, 1, 16);
    vec3 ref = vec3(0.0);
    vec3 s2 = vec3(0.0), s4 = vec3(0.0), s8 = vec3(0.0), s16 = vec3(0.0);
    vec3 s64 = vec3(0.0), s256 = vec3(0.0);
    vec3 alb = vec3(0.0);
    for (int k = 0; k < 16; k++) {
        bool want_ref = k < aa;
        if (!want_ref && u_mc == 0) break;
        Geom g = trace(base + aa_offset(pixel, k));
        if (want_ref) {
            ref += expected_colour(g);
            alb += g.albedo;
        }
        if (u_mc != 0) {
            for (int j = 0; j < 16; j++) {
                rng_init(pixel, uint(k * 16 + j));
                vec3 e = estimate_colour(g);
                s256 += e;
                if (j < 4) s64 += e;
                if (j == 0) {
                    s16 += e;
                    if (k < 8) s8 += e;
                    if (k < 4) s4 += e;
                    if (k < 2) s2 += e;
                }
            }
        }
    }
    out0 = vec4(ref / float(aa), 1.0);
    out1 = vec4(s2 / 2.0, 1.0);
    out2 = vec4(s4 / 4.0, 1.0);
    out3 = vec4(s8 / 8.0, 1.0);
    out4 = vec4(s16 / 16.0, 1.0);
    out5 = vec4(s64 / 64.0, 1.0);
    out6 = vec4(s256 / 256.0, 1.0);
    out7 = vec4(alb / float(aa), 1.0);
}
