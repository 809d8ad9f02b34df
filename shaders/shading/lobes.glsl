// The lobes of a physically based pixel (lighting.frag with PBR defined): Kautz and McCool's fitted
// tables (renderer/lighting/material_lobes.py), read by roughness and view elevation, bilinear.
// Included after the globals of lighting.frag.
//
// The table (binding 7): the GGX table from 0, the sheen table from u_sheen_offset, each
// TABLE_R x TABLE_J cells, roughness-major, of 3 scalars then (weight, 1 / s, psi) per lobe, the weight
// relative to the energy (the lobes are clipped at the horizon, where their parts above it sum to 1).
layout(std430, binding = BUF_MATERIAL_LOBES) readonly buffer MaterialLobes { float lobe_table[]; };
uniform int u_sheen_offset;

const float TABLE_DTHETA = TABLE_THETA_MAX / float(TABLE_J - 1);
const float TABLE_DR = (1.0 - TABLE_R0) / float(TABLE_R - 1);

// Bilinear weights of (roughness, theta_v) on the nodes: cells (i, j), (i + 1, j), (i, j + 1),
// (i + 1, j + 1) and their weights.
struct TableAt { int i; int j; float fx; float fy; };

TableAt table_at(float roughness, float theta) {
    float x = clamp((roughness - TABLE_R0) / TABLE_DR, 0.0, float(TABLE_R - 1));
    float y = clamp(theta / TABLE_DTHETA, 0.0, float(TABLE_J - 1));
    TableAt t;
    t.i = min(int(x), TABLE_R - 2);
    t.j = min(int(y), TABLE_J - 2);
    t.fx = x - float(t.i);
    t.fy = y - float(t.j);
    return t;
}

float table_value(int base, int cell, TableAt t, int field) {
    int c00 = base + (t.i * TABLE_J + t.j) * cell + field;
    int di = TABLE_J * cell;
    return mix(mix(lobe_table[c00], lobe_table[c00 + di], t.fx),
               mix(lobe_table[c00 + cell], lobe_table[c00 + di + cell], t.fx), t.fy);
}

// Sets lobe slot `first + k` for each of `count` lobes of the table at `base`, with the energy
// `energy` times each lobe's relative weight (globals of lighting.frag).
void table_lobes(int base, int count, TableAt t, vec3 n, vec3 tangent, vec3 energy, int first) {
    int cell = 3 + 3 * count;
    for (int k = 0; k < count; ++k) {
        float weight = table_value(base, cell, t, 3 + 3 * k);
        float inv_s = max(table_value(base, cell, t, 4 + 3 * k), 0.0);
        float psi = table_value(base, cell, t, 5 + 3 * k);
        g_lobe_axis[first + k] = normalize(cos(psi) * n + sin(psi) * tangent);
        g_lobe_inv_s[first + k] = inv_s;
        g_lobe_level[first + k] = gloss_level(1.0 - min(inv_s, 1.0));   // a lobe wider than a cosine: the cosine's level
        g_lobe_weight[first + k] = weight * energy;
    }
}

#include "shading/anisotropy.glsl"

// The pixel's material, for the exact terms of the lights no wider than its lobe (pbr_from_light_above).
vec3 g_pbr_n = vec3(0.0, 0.0, 1.0);
// An anisotropic pixel's GGX (brdf.py): its frame (t along the stretch, b = n x t, both perpendicular
// to the facing normal) and widths alpha_t = alpha / k, alpha_b = alpha k, k = sqrt(1 - 0.9 a).
bool g_pbr_anisotropic = false;
float g_pbr_anisotropy = 0.0;
vec3 g_pbr_t = vec3(1.0, 0.0, 0.0);
vec3 g_pbr_b = vec3(0.0, 1.0, 0.0);
float g_pbr_at = 0.25;
float g_pbr_ab = 0.25;
vec3 g_pbr_f0 = vec3(0.04);
float g_pbr_alpha = 0.25;
vec3 g_pbr_sheen = vec3(0.0);
float g_pbr_sheen_alpha = 0.25;
float g_pbr_below = 1.0;            // the sheen layer's albedo scaling of the layer below
vec3 g_pbr_exact = vec3(0.0);       // those lights' specular and sheen terms, summed

// A small light's specular and sheen terms from the exact BRDF (renderer/shading/brdf.py: GGX with
// the height-correlated Smith visibility and Schlick's Fresnel, Charlie with Neubelt's visibility) at
// its disc's centre l, energy E. The disc's spread widens GGX's: in the small-slope picture a disc of
// angular radius a spreads the half vector uniformly over a / 2, slope variance a^2 / 16 per axis,
// which adds to GGX's alpha^2 / 2: alpha'^2 = alpha^2 + a^2 / 8 (the same argument as the Phong
// lobe's in discs.glsl). Sheen is broad: its centre value stands for the disc.
vec3 pbr_disc(vec3 l, float sin_a, vec3 energy) {
    vec3 n = g_pbr_n, v = g_to_eye;
    float nl = dot(n, l);
    if (nl <= 0.0) return vec3(0.0);
    float nv = max(dot(n, v), 1e-4);
    vec3 h = normalize(v + l);
    float nh = clamp(dot(n, h), 0.0, 1.0), vh = clamp(dot(v, h), 0.0, 1.0);
    float widen = 0.125 * sin_a * sin_a;
    float dist, vis;
    if (g_pbr_anisotropic) {
        // The anisotropic GGX (brdf.py), each width widened by the disc as alpha is below.
        float at = sqrt(g_pbr_at * g_pbr_at + widen), ab = sqrt(g_pbr_ab * g_pbr_ab + widen);
        float ht = dot(h, g_pbr_t) / at, hb = dot(h, g_pbr_b) / ab;
        float d = ht * ht + hb * hb + nh * nh;
        dist = 1.0 / (PI * at * ab * d * d);
        float vt = at * dot(v, g_pbr_t), vb = ab * dot(v, g_pbr_b);
        float lt = at * dot(l, g_pbr_t), lb = ab * dot(l, g_pbr_b);
        float lambda_v = 0.5 * (sqrt(1.0 + (vt * vt + vb * vb) / (nv * nv)) - 1.0);
        float lambda_l = 0.5 * (sqrt(1.0 + (lt * lt + lb * lb) / (nl * nl)) - 1.0);
        vis = 1.0 / (4.0 * nv * nl * (1.0 + lambda_v + lambda_l));
    } else {
        float a2 = g_pbr_alpha * g_pbr_alpha + widen;
        float d = nh * nh * (a2 - 1.0) + 1.0;
        dist = a2 / (PI * d * d);
        vis = 0.5 / max(nl * sqrt(nv * nv * (1.0 - a2) + a2) + nv * sqrt(nl * nl * (1.0 - a2) + a2), 1e-30);
    }
    vec3 fresnel = g_pbr_f0 + (1.0 - g_pbr_f0) * pow(1.0 - vh, 5.0);
    vec3 f = g_pbr_below * fresnel * (dist * vis);
#if LOBES_SHEEN > 0
    float inv = 1.0 / g_pbr_sheen_alpha;
    float charlie = (2.0 + inv) * pow(max(1.0 - nh * nh, 0.0), 0.5 * inv) / (2.0 * PI);
    f += g_pbr_sheen * (charlie / (4.0 * (nl + nv - nl * nv)));
#endif
    return energy * f * nl;
}

// A disc's exact terms above the plane of `p` (the horizon that cuts more of it, lighting.frag): the
// terms at the centre of its part above the plane, times that part's share of its energy (linear in
// the cosine, discs.glsl's disc_share_above). A disc whose centre has set still lights the pixel with
// its upper part.
vec3 pbr_disc_above(vec3 l, float sin_a, vec3 energy, vec3 p) {
    float x = -dot(p, l) / max(sin_a, 1e-6);
    if (x <= -1.0) return pbr_disc(l, sin_a, energy);
    if (x >= 1.0) return vec3(0.0);
    float share = 0.5 - 0.5 * x;
    vec3 t = p - dot(p, l) * l;
    float len = length(t);
    if (len < 1e-6) return share * pbr_disc(l, sin_a, energy);
    return share * pbr_disc(normalize(l + (0.5 * (x + 1.0) * sin_a / len) * t), sin_a, energy);
}

vec3 pbr_from_light_above(int i, vec3 p) {
#ifdef SUB_LIGHTS
    vec3 sum = vec3(0.0);
    for (int j = 0; j < SUB_LIGHTS; ++j) {   // a constant count: the driver writes the loop out
        int k = i * SUB_LIGHTS + j;
        sum += pbr_disc_above(sub_lights[k].dir_sin.xyz, sub_lights[k].dir_sin.w, sub_lights[k].energy.rgb, p);
    }
    return sum;
#else
    return pbr_disc_above(lights[i].dir_scale.xyz, lights[i].params.w, lights[i].energy.rgb, p);
#endif
}

// Whether light i's glossy terms on a physically based pixel come from the exact BRDF over its disc
// (pbr_from_light_above) instead of the fitted lobes: a small light's without its PEM, and under
// GLOSSY_WIDE every light whose disc is no wider than GGX's alpha. There the small-slope widening of
// pbr_disc holds (the disc's spread is at most the lobe's own) and the exact value is what the fit
// misses most: towards grazing views the fitted lobes lose the GGX tail (docs/brdf-lobes.md). A wider
// disc keeps its PEM: the widened lobe at its centre is narrower than the disc's true highlight, and
// the lights of a bright area would print as spots (measured on a white furnace of 48 lights: the
// worst 1 % of a metal's pixels 55 % off under alpha'^2 <= 8 alpha^2, 18 % under this rule).
bool pbr_exact_light(int i, bool small, bool pem_glossy) {
    if (small && !pem_glossy) return true;
#ifdef GLOSSY_WIDE
    return lights[i].params.w <= g_pbr_alpha;
#else
    return false;
#endif
}

// The BRDF is defined on the normal's hemisphere only: a normal turned to the seen side that still
// leans away from the eye (a fold's lip, a silhouette) is bent towards the view until n.v is
// MIN_N_DOT_V (renderer/reference/montecarlo.py, facing_normal: the same rule).
const float MIN_N_DOT_V = 0.05;

vec3 facing_normal(vec3 n, vec3 v) {
    float nv = dot(n, v);
    vec3 p = n - nv * v;
    float len = length(p);
    if (nv >= MIN_N_DOT_V || len <= 1e-12) return n;
    return sqrt(1.0 - MIN_N_DOT_V * MIN_N_DOT_V) * p / len + MIN_N_DOT_V * v;
}

// An anisotropic pixel's frame from its target's code (anisotropy.glsl), packed against the normal
// the geometry pass wrote (`stored`), made perpendicular to the facing normal n.
void pbr_anisotropy(float code, vec3 stored, vec3 n) {
    vec3 t;
    g_pbr_anisotropic = anisotropy_unpack(code, stored, g_pbr_anisotropy, t);
    if (!g_pbr_anisotropic) return;
    t -= dot(t, n) * n;
    float len = length(t);
    if (len < 1e-6) {   // the facing normal turned onto the direction: isotropic here
        g_pbr_anisotropic = false;
        return;
    }
    g_pbr_t = t / len;
    g_pbr_b = cross(n, g_pbr_t);
}

// glTF metallic-roughness (base colour, metallic, roughness) under a Charlie sheen layer (colour,
// roughness): sets the pixel's lobes and returns the weight of its diffuse term. n: the facing normal.
vec3 pbr_lobes(vec3 n, vec3 to_eye, vec3 base, float metallic, float roughness, vec3 sheen, float sheen_roughness) {
    roughness = max(roughness, TABLE_R0);
    sheen_roughness = max(sheen_roughness, TABLE_R0);
    float nv = clamp(dot(n, to_eye), 0.0, 1.0);
    float theta = acos(nv);
    vec3 tangent = to_eye - nv * n;   // in the plane of n and v, towards v
    float len = length(tangent);
    tangent = len > 1e-6 ? tangent / len : (abs(n.z) < 0.9 ? normalize(cross(n, vec3(0.0, 0.0, 1.0)))
                                                          : normalize(cross(n, vec3(1.0, 0.0, 0.0))));
    TableAt t = table_at(roughness, theta);
    int cell = 3 + 3 * LOBES_GGX;
    float a = table_value(0, cell, t, 0), b = table_value(0, cell, t, 1), c = table_value(0, cell, t, 2);
    vec3 f0 = mix(vec3(0.04), base, metallic);
    vec3 specular = f0 * a + b;
    vec3 diffuse = (1.0 - f0) * (1.0 - metallic) * base * c;
    g_pbr_n = n;
    g_pbr_f0 = f0;
    g_pbr_alpha = roughness * roughness;
    if (g_pbr_anisotropic) {
        float k = sqrt(1.0 - 0.9 * g_pbr_anisotropy);
        g_pbr_at = g_pbr_alpha / k;
        g_pbr_ab = g_pbr_alpha * k;
    }
    g_pbr_sheen = sheen;
    g_pbr_sheen_alpha = sheen_roughness * sheen_roughness;
#if LOBES_SHEEN > 0
    TableAt ts = table_at(sheen_roughness, theta);
    float e_sheen = table_value(u_sheen_offset, 3 + 3 * LOBES_SHEEN, ts, 0);
    // KHR_materials_sheen's albedo scaling of the layer below.
    float below = 1.0 - max(max(sheen.r, sheen.g), sheen.b) * e_sheen;
    specular *= below;
    diffuse *= below;
    g_pbr_below = below;
    table_lobes(u_sheen_offset, LOBES_SHEEN, ts, n, tangent, sheen * e_sheen, LOBES_GGX);
#endif
    if (g_pbr_anisotropic) {
        // The fitted lobes are round: an anisotropic pixel's are those of the round GGX whose width
        // has the same mean square, sqrt((alpha_t^2 + alpha_b^2) / 2), at the pixel's own specular
        // energy. Measured on the fabric bench's satin (docs/materials.md): closer to the reference than
        // the lobes of alpha itself, and than lobes about a normal bent across the stretch (Filament's
        // image-based anisotropy, which moved the dress's highlights off their place).
        float width = sqrt(sqrt(0.5 * (g_pbr_at * g_pbr_at + g_pbr_ab * g_pbr_ab)));
        t = table_at(width, theta);
    }
    table_lobes(0, LOBES_GGX, t, n, tangent, specular, 0);
    return diffuse;
}
