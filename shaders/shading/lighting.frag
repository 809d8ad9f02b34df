// Lighting pass of the deferred shading (one full-screen triangle; the geometry pass,
// gbuffer.frag, has written position, normals and material per pixel), Knuth et al. 2014 Eq. 5:
// c = sum_i VIS_i * PEM_i(dir, g).
// The PEMs hold solid-angle weighted chains A_i (renderer/lighting/pem_reference.py): a lookup is
// A_i(dir) / B(dir), and B, the same for every region, is read once per direction.
// Diffuse: PEM_i looked up along the normal at the calibrated s = 1 level, times the albedo.
// Glossy: PEM_i looked up along the reflection vector at the level calibrated for g, times the
// specular weight. VIS_i is the variance-shadow-map visibility of light i.
//
// MODE (a #define, one program per mode: llvmpipe runs both sides of uniform branches under a mask,
// so unused modes would cost time): 0 full method, 1 no occlusion, 2 grey AO, 3 colour AO,
// 4 the many-light baseline.
//
// Lights come in kinds, for the same reason: which of its PEMs a light reads (diffuse, glossy: a small
// light's terms may be in closed form instead), which shadow-map array holds its map, and which PEM
// texture holds its region. The renderer sorts the lights by kind (light_order, u_kind_end) and each
// kind has a loop of its own in which those choices are constants, so that no light pays for the
// lookups and closed forms of another kind (renderer.py, light_kinds).
#include "common/lights.glsl"

#ifdef LIGHTING_COMPUTE
// The same pass as a compute shader, one invocation per pixel (renderer.py, Renderer.lighting_pass):
// GPUs built for compute (an H100 rasterizes on a few of its multiprocessors) run it on all of them.
// Uncovered pixels (the geometry pass's position.w = -1) keep the background drawn before.
layout(local_size_x = 8, local_size_y = 8) in;
layout(rgba32f, binding = 0) writeonly uniform image2D o_image;
#else
// The full-screen triangle lies at the far plane and the depth test is GREATER against the geometry
// pass's depth: only covered pixels pass, and blocks with none are skipped before shading.
layout(early_fragment_tests) in;
#endif

layout(std430, binding = 0) readonly buffer Lights { Light lights[]; };
layout(std430, binding = 1) readonly buffer GlossLevels { float level_of_g[]; };  // GLOSS_TABLE_SIZE
layout(std430, binding = 4) readonly buffer LightOrder { int light_order[]; };      // the lights by kind
layout(binding = 0) uniform samplerCubeArray u_pem0;         // layer i = region i < 192, scaled by 1/scale_i
layout(binding = 5) uniform samplerCubeArray u_pem1;         // layer i - 192 = region i >= 192
layout(binding = 6) uniform samplerCubeArray u_pem_norm;     // layer 0: B = chain(w), the normalizer
layout(binding = 1) uniform sampler2DArray u_moments;        // blurred moments, layer shadow.x of light i
layout(binding = 12) uniform sampler2DArray u_moments_sharp; // the small lights' (shadow.y = 1), larger maps
layout(binding = 8) uniform sampler2D u_g_position;         // the geometry pass's targets (gbuffer.frag)
layout(binding = 9) uniform sampler2D u_g_normal;
layout(binding = 10) uniform sampler2D u_g_geometric;
layout(binding = 11) uniform sampler2D u_g_albedo;

uniform vec3 u_camera_pos;
uniform int u_n_lights;
// light_order[u_kind_end[k - 1] .. u_kind_end[k]) are the lights of kind k: bit 0 reads its diffuse
// PEM, bit 1 its glossy PEM, bit 2 its map is in the sharp array, bit 3 its region is in u_pem1.
uniform int u_kind_end[16];
uniform float u_diffuse_level;
uniform float u_min_sigma_texels;  // FrameSettings.min_sigma_texels: least deviation of the depths under a texel
uniform float u_bleed_reduction;   // Lauritzen's light-bleeding reduction: clip p_max below this
uniform float u_normal_offset_texels;  // the shadow lookup pushed off the surface along n, in the light's own texels
                                   // 2 each light's disc share above the triangle's plane, 3 both
                                   // (FrameSettings.glossy_horizon)

#ifndef LIGHTING_COMPUTE
out vec4 o_color;
#endif

const float PI = 3.14159265358979;

float linstep(float lo, float hi, float x) { return clamp((x - lo) / (hi - lo), 0.0, 1.0); }

// Chebyshev's one-tailed inequality on blurred depth moments m at receiver depth t (Donnelly &
// Lauritzen 2006), with a least variance.
float chebyshev(vec2 m, float t, float least_variance) {
    if (t <= m.x) return 1.0;
    float variance = max(m.y - m.x * m.x, least_variance);
    float d = t - m.x;
    return linstep(u_bleed_reduction, 1.0, variance / (variance + d * d));
}

// The pixel's shadow group (gbuffer.frag, renderer/scene.py): 0 or 1, SHADOW_GROUPS if it casts nothing.
const int SHADOW_GROUPS = 2;
int g_shadow_group = 0;
uniform bool u_two_groups;   // the maps hold both groups' moments (RGBA); else group 0's alone (RG)

// A light's blurred moments at uv; outside the map nothing casts (it is fitted to the casters).
vec4 moments(vec2 uv, float layer, bool sharp) {
    if (any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) return vec4(1.0);
    return sharp ? texture(u_moments_sharp, vec3(uv, layer)) : texture(u_moments, vec3(uv, layer));
}

// VIS_i from the light's variance shadow map: the smaller of the receiver's own group's visibility
// and the other group's. Against its own group a surface needs a bias not to shadow itself (the
// lookup pushed off it along n, a floor on the depths' deviation); against the other group it does
// not (it is not in that group's map), so a garment shadows the body under it however small the gap.
float visibility(int i, vec3 ws_pos, vec3 n, bool sharp) {
    float layer = lights[i].shadow.x;
    if (layer < 0.0) return 1.0;   // no shadow map: the PEM is added unshadowed
    // The receiver's own group at the point pushed off the surface along n, by an offset in the
    // light's own texels (a sharp map's are smaller); the other group at the surface itself.
    bool receiver_only = g_shadow_group >= SHADOW_GROUPS;
    float offset = receiver_only ? 0.0 : u_normal_offset_texels * lights[i].shadow.z;
    vec4 p0 = lights[i].view_proj * vec4(ws_pos, 1.0);
    vec4 p = p0 + offset * (lights[i].view_proj * vec4(n, 0.0));
    // A receiver behind every caster (beyond the far plane, e.g. a floor that casts nothing) is compared
    // at the far plane: lit where no caster is, shadowed where one is.
    float t = min(p.z, 1.0), t0 = min(p0.z, 1.0);
    vec4 m = moments(p.xy * 0.5 + 0.5, layer, sharp);
    if (receiver_only) {
        float v = chebyshev(m.xy, t0, 1e-7);
        return u_two_groups ? min(v, chebyshev(m.zw, t0, 1e-7)) : v;
    }
    // The depths under one texel spread by about a texel where the surface slopes: a floor on the
    // deviation, in the light's own texels, keeps a surface from shadowing itself.
    float floor_sigma = u_min_sigma_texels * lights[i].params.y;
    // 1e-7: float32's cancellation in m.y - m.x^2 (depths in [0, 1]), the floor when the knob is 0.
    float own = chebyshev(g_shadow_group == 0 ? m.xy : m.zw, t, max(floor_sigma * floor_sigma, 1e-7));
    if (!u_two_groups) return own;
    vec4 m0 = moments(p0.xy * 0.5 + 0.5, layer, sharp);
    return min(own, chebyshev(g_shadow_group == 0 ? m0.zw : m0.xy, t0, 1e-7));
}

#ifdef CONTACT_SHADOWS
// Contact shadows (full mode): occluders nearer than a shadow map resolves. A light's map sees
// nothing closer than its normal offset and its variance floor, a few of its texels (millimetres on
// a garment): a collar over the neck, a fold's lips. The geometry pass's positions do: per pixel, the
// neighbours within u_contact_radius (world units) along CONTACT_SLICES screen lines through the
// pixel, each line with the eye a plane that holds the view direction (a slice). Each neighbour that
// rises above the pixel's own plane is solid from its front (what the camera sees) to
// u_contact_thickness behind it, and hides that range of angles from the view direction in its
// slice: a mask of 32 sectors per half-slice (visibility bitmasks, after Therrien et al. 2023, here
// uniform in the cosine so that no angle needs an acos). A light lies in the half-slice of its own
// screen direction; the occluded share of its disc (its angular radius either side of its own
// sector, half a sector at least) is read from the masks of the two neighbouring half-slices and
// interpolated. VIS_i takes the smaller of this and the shadow map's. Only what the camera sees can
// occlude (what hides behind the visible surface is the map's), within the radius only; a finite
// thickness keeps a garment's near layer at a silhouette from shadowing the far layer from a light
// behind both, which a horizon (a height field: everything behind the front is solid) did.
uniform mat4 u_view_proj;        // the camera's
uniform vec2 u_image_size;       // pixels
uniform float u_focal_px;        // pixels per unit of view-space slope: height / (2 tan(fov_y / 2))
uniform float u_contact_radius;  // world units
uniform float u_contact_thickness;  // world units (renderer.py, CONTACT_THICKNESS)
// Sine of the least elevation above the triangle's plane at which a neighbour occludes: a mesh's
// facets bend by a few degrees between neighbouring pixels on a smooth surface.
const float CONTACT_MIN_ELEVATION = 0.1;
const int CONTACT_DIRS = 2 * CONTACT_SLICES;   // screen direction k at angle k pi / CONTACT_SLICES
// Per direction: the occluded sectors of its half-plane, 32 bits uniform in (1 - cos) / 2 of the
// angle from the view direction (bit 0 along it, bit 31 opposite).
uint g_sectors[CONTACT_DIRS];
// Per light: xyz = x, y, w of the camera's view_proj times (direction, 0); w: its angular radius,
// at least 0.01 radians.
layout(std430, binding = 5) readonly buffer LightScreen { vec4 light_screen[]; };
vec4 g_clip;                     // the pixel's clip-space position

// Bits [a, b) of a 32-bit mask (a, b in 0..32).
uint bit_range(int a, int b) {
    if (b <= a) return 0u;
    uint hi = b >= 32 ? 0xffffffffu : (1u << uint(b)) - 1u;
    return hi & ~((1u << uint(a)) - 1u);
}

void contact_sectors(vec3 p, vec3 v, vec3 plane, ivec2 px) {
    g_clip = u_view_proj * vec4(p, 1.0);
    ivec2 size = ivec2(u_image_size);
    float radius_px = u_contact_radius * u_focal_px / max(g_clip.w, 1e-30);
    // A step per two pixels of the radius, at most CONTACT_STEPS.
    int steps = clamp(int(ceil(0.5 * radius_px)), 1, CONTACT_STEPS);
    for (int k = 0; k < CONTACT_DIRS; ++k) {
        float phi = float(k) * (PI / float(CONTACT_SLICES));
        vec2 d = vec2(cos(phi), sin(phi));
        d /= max(abs(d.x), abs(d.y));   // whole pixels along the major axis
        uint mask = 0u;
        for (int j = 1; j <= steps; ++j) {
            // Denser near the pixel (the nearest occluders are the ones the maps miss), a pixel apart at least.
            float t = float(j) / float(steps);
            ivec2 q = px + ivec2(round(d * max(radius_px * t * t, float(j))));
            if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, size))) break;
            vec4 s = texelFetch(u_g_position, q, 0);
            if (s.w < 0.0) continue;   // no surface there (the geometry pass clears w to -1)
            vec3 e = s.xyz - p;
            float len = length(e);
            // Only what rises above the surface's own plane: the plane itself is the terminator's and
            // the PEMs' (a flat or convex neighbourhood hides nothing more).
            if (!(dot(e, plane) > CONTACT_MIN_ELEVATION * len)) continue;
            // Solid from its front (what the camera sees) to u_contact_thickness behind it (along the
            // pixel's view direction, near enough to the sample's own within the radius); over the
            // radius' outer half the range shrinks to its front, so that an occluder crossing the
            // radius does not flicker.
            float w = 1.0 - smoothstep(0.5 * u_contact_radius, u_contact_radius, len);
            vec3 b = e - u_contact_thickness * v;
            float front = 16.0 * (1.0 - dot(e, v) / len);
            float back = 16.0 * (1.0 - dot(b, v) / max(length(b), 1e-30));
            mask |= bit_range(int(round(front)), int(round(mix(front, back, w))));
        }
        g_sectors[k] = mask;
    }
}

// The occluded sectors of a mask up to x (in sectors, 0..32), the last partly.
float sectors_below(uint mask, float x) {
    if (x <= 0.0) return 0.0;
    if (x >= 32.0) return float(bitCount(mask));
    int i = int(x);
    return float(bitCount(mask & bit_range(0, i))) + fract(x) * float((mask >> uint(i)) & 1u);
}

float contact_visibility(int i, vec3 v) {
    vec4 ls = light_screen[i];
    // The screen direction of the light at the pixel: d(ndc)/dt of p + t l, in pixels (a positive
    // factor dropped).
    vec2 d = (ls.xy * g_clip.w - g_clip.xy * ls.z) * u_image_size;
    // Its angle as a "diamond angle" in [0, 4): 0, 1, 2, 3 at 0, 90, 180, 270 degrees, 0.5 at 45,
    // monotonic between (exact at the slices' directions: they are the weights' nodes), no atan.
    float s = abs(d.x) + abs(d.y);
    vec2 u = s > 0.0 ? d / s : vec2(1.0, 0.0);
    float dia = u.y >= 0.0 ? (u.x >= 0.0 ? u.y : 1.0 - u.x) : (u.x < 0.0 ? 2.0 - u.y : 3.0 + u.x);
    float x = dia * (float(CONTACT_SLICES) / 2.0);
    int k0 = min(int(x), CONTACT_DIRS - 1);
    int k1 = (k0 + 1) % CONTACT_DIRS;
    float c = dot(lights[i].dir_scale.xyz, v);
    // The light's disc as an interval of sectors around its own (half a sector at least), moved
    // inside [0, 32] where it would reach past the view direction or its opposite (there the cosine
    // folds back: no part of the disc lies beyond), the occluded share of it per slice, then between
    // the two slices.
    float centre = 16.0 * (1.0 - c);
    float half_width = clamp(16.0 * sqrt(max(1.0 - c * c, 0.0)) * ls.w, 0.5, 16.0);
    float lo = clamp(centre - half_width, 0.0, 32.0 - 2.0 * half_width), hi = lo + 2.0 * half_width;
    float occ0 = sectors_below(g_sectors[k0], hi) - sectors_below(g_sectors[k0], lo);
    float occ1 = sectors_below(g_sectors[k1], hi) - sectors_below(g_sectors[k1], lo);
    return 1.0 - clamp(mix(occ0, occ1, x - float(k0)) / (2.0 * half_width), 0.0, 1.0);
}
#endif

float gloss_level(float g) {
    float x = clamp(g, 0.0, 1.0) * float(GLOSS_TABLE_SIZE - 1);
    int k = min(int(x), GLOSS_TABLE_SIZE - 2);
    return mix(level_of_g[k], level_of_g[k + 1], x - float(k));
}

// SMALL_LIGHT_MAX_SIN (a #define, renderer/shadows/lights.py): lights of angular radius up to ~5.7
// degrees count as small.

// Accumulators of main(), shared with add_light() (GLSL has no closures).
vec3 g_geometric_normal = vec3(0.0, 0.0, 1.0);  // the triangle's plane, facing the camera
vec3 g_to_eye = vec3(0.0, 0.0, 1.0);            // unit, from the pixel's surface point to the eye
vec3 g_reflect = vec3(0.0, 0.0, 1.0);           // the view direction reflected about the shading normal
vec3 g_diffuse = vec3(0.0), g_glossy = vec3(0.0), g_ao_rgb = vec3(0.0), g_ao_norm = vec3(0.0);

// Adds light i, given its PEM looked up along the normal (pem_d, diffuse level) and along the
// reflection vector (pem_g, level of g), both still divided by the region's scale.
// The diffuse term from the light itself instead of its PEM: the region as a uniform disc of angular
// radius a (its mean cosine (1 + cos a) / 2 is the region's, renderer/lighting/median_cut.py) carrying
// the region's energy E. Radiance = E / (pi * Omega(a)) * integral over the disc of max(0, n.w) dw;
// the integral is pi sin^2(a) mu when the disc is above the horizon (mu = n.l >= sin a), and otherwise
// the closed form of a horizon-clipped uniform cap (Snyder 1996, "Area light sources for real-time
// graphics"; the form used for sphere lights by Lagarde and de Rousiers 2014). Exact for a region
// above the horizon whatever its shape; no texture lookup.
vec3 diffuse_from_light(int i, vec3 n) {
    float mu = dot(n, lights[i].dir_scale.xyz);
    float sin_a = lights[i].params.w;
    float sin2 = sin_a * sin_a;
    float cos_a = sqrt(max(1.0 - sin2, 0.0));
    float integral;
    if (mu >= sin_a) {
        integral = PI * sin2 * mu;
    } else if (mu <= -sin_a) {
        integral = 0.0;
    } else if (sin_a < 0.01) {
        // A tiny disc straddling the horizon: the closed form cancels in float32 here; the share of
        // the disc above the plane times its mean cosine there, (mu + sin a)^2 / (4 sin a), is within
        // a fraction of a percent of the peak.
        integral = PI * sin2 * (mu + sin_a) * (mu + sin_a) / (4.0 * sin_a);
    } else {
        float sin_t = sqrt(max(1.0 - mu * mu, 1e-12));
        float cot_a = cos_a / sin_a;
        float y = clamp(-cot_a * mu / sin_t, -1.0, 1.0);
        float q = sin_t * sqrt(max(1.0 - y * y, 0.0));
        integral = max((mu * acos(y) - cot_a * q) * sin2 + atan(q, cot_a), 0.0);
    }
    float omega = 2.0 * PI * sin2 / (1.0 + cos_a);   // 2 pi (1 - cos a), without cancellation
    return lights[i].energy.rgb * (integral / (PI * max(omega, 1e-30)));
}

#ifdef SUB_LIGHTS
// FrameSettings.sub_lights: a region's glossy term in closed form summed over SUB_LIGHTS discs, its
// texels cut further by the same median cut (renderer/lighting/median_cut.py, SubLights); its
// visibility, diffuse term and PEMs stay the region's.
struct SubLight { vec4 dir_sin; vec4 energy; };   // unit direction, sine of the disc's radius; rgb
layout(std430, binding = 6) readonly buffer SubLights { SubLight sub_lights[]; };
#endif

vec3 g_diffuse_exact = vec3(0.0);   // the closed-form terms, added after the PEM terms' normalization
vec3 g_glossy_exact = vec3(0.0);
float g_gloss = 0.0;                // the pixel's glossiness g
bool g_has_glossy = false;          // specular > 0

// A small light's glossy term without its PEM: the region as a disc of angular radius a carrying its
// energy E, seen through the normalized Phong lobe of exponent s around r (paper Eq. 3). The disc's
// spread widens the lobe: in the small-angle (Gaussian) picture cos^s has variance 1 / s per axis and
// a uniform disc a^2 / 4, which add, so the lobe of exponent s' = 1 / (1 / s + a^2 / 4) carries E.
// Finite at g = 1 (the mirror): s' is then bounded by the disc's own size.
vec3 glossy_disc(vec3 l, float sin_a, vec3 energy, vec3 r) {
    float inv_s = max(1.0 - g_gloss, 0.0);
    float s = 1.0 / max(inv_s + 0.25 * sin_a * sin_a, 1e-6);
    float c = clamp(dot(r, l), 0.0, 1.0);   // float32 can reach 1 + 1e-7; s' up to ~4e6
    return energy * ((s + 1.0) / (2.0 * PI) * pow(c, s));
}

vec3 glossy_from_light(int i, vec3 r) {
#ifdef SUB_LIGHTS
    vec3 sum = vec3(0.0);
    for (int k = i * SUB_LIGHTS; k < (i + 1) * SUB_LIGHTS; ++k)
        sum += glossy_disc(sub_lights[k].dir_sin.xyz, sub_lights[k].dir_sin.w, sub_lights[k].energy.rgb, r);
    return sum;
#else
    return glossy_disc(lights[i].dir_scale.xyz, lights[i].params.w, lights[i].energy.rgb, r);
#endif
}

// Share of light i's energy, a disc of angular radius r (sin r = params.w) around its direction,
// above the plane of `normal` (linear in the cosine across the disc).
float disc_share_above(int i, vec3 normal) {
    float sin_r = lights[i].params.w;
    return clamp((dot(normal, lights[i].dir_scale.xyz) + sin_r) / (2.0 * sin_r), 0.0, 1.0);
}

// GLOSSY_WIDE (glossy "wide"): a large light's glossy term in closed form too where the lobe is wider
// than its disc (variance 1 / s >= a^2 / 4, the two spreads of glossy_from_light): there the PEM's
// coarse MIP levels (a few texels a face) are the larger error; a narrower lobe reads the fine levels,
// which hold the region's own detail that a disc does not. Per pixel: g may vary.
bool wide_lobe(int i) {
#ifdef GLOSSY_WIDE
    float sin_a = lights[i].params.w;
    return max(1.0 - g_gloss, 0.0) >= 0.25 * sin_a * sin_a;
#else
    return false;
#endif
}

// pem_diffuse / pem_glossy: the light's terms come from its PEMs (else in closed form); sharp: its map is in the sharp array. Constants of the
// caller's loop (see main()).
void add_light(int i, vec3 pem_d, vec3 pem_g, vec3 n, vec3 ws_pos, bool pem_diffuse, bool pem_glossy, bool sharp) {
    float scale = lights[i].dir_scale.w;
    pem_d *= scale;
    pem_g *= scale;
#if MODE == 1
    if (!pem_diffuse) g_diffuse_exact += diffuse_from_light(i, n);
    else g_diffuse += pem_d;
    if (!pem_glossy || wide_lobe(i)) { if (g_has_glossy) g_glossy_exact += glossy_from_light(i, g_reflect); }
    else g_glossy += pem_g;
#elif MODE == 0
    float vis = visibility(i, ws_pos, n, sharp);
#ifdef CONTACT_SHADOWS
    if (lights[i].shadow.x >= 0.0) vis = min(vis, contact_visibility(i, g_to_eye));
#endif
    // Light from below the surface's own plane (the triangle's, not the interpolated normal's) is
    // blocked by the surface for a closed body and by the body under a garment; a shadow map cannot
    // resolve it at the terminator, where the surface is its own occluder at grazing angles. Share of
    // the light's disc above that plane:
    float sin_r = lights[i].params.w;
    float above = disc_share_above(i, g_geometric_normal);
    // Small lights (a sun): both terms (their terminator is sharp; a large region's share is soft
    // and its PEM's diffuse kernel spreads it anyway); large lights: the glossy term (the lobe's part
    // below the surface, which the reference's visibility removes and the PEM lookup along r does not).
    bool small = sin_r <= SMALL_LIGHT_MAX_SIN;
    if (small) vis *= above;
    if (pem_diffuse) g_diffuse += vis * pem_d;
    else g_diffuse_exact += vis * diffuse_from_light(i, n);
    if (!small) vis *= above;
    if (!pem_glossy || wide_lobe(i)) {
        if (g_has_glossy) g_glossy_exact += vis * glossy_from_light(i, g_reflect);
    } else {
        g_glossy += vis * pem_g;
    }
#else
    // Ambient-occlusion baselines (paper Fig. 6): unshadowed lighting times an occlusion factor
    // that averages VIS_i with cosine weights, by solid angle (grey) or by energy (colour).
    float vis = visibility(i, ws_pos, n, sharp);
    float cosine = max(dot(n, lights[i].dir_scale.xyz), 0.0);
    vec3 w = MODE == 2 ? vec3(lights[i].params.z) : lights[i].energy.rgb;
    g_ao_rgb += vis * cosine * w;
    g_ao_norm += cosine * w;
    g_diffuse += pem_d;
    g_glossy += pem_g;
#endif
}

// One light of a kind: its PEM lookups (region i in u_pem0, or in u_pem1 when in_pem1), then add_light.
void shade_light(int i, bool pem_diffuse, bool pem_glossy, bool sharp, bool in_pem1, vec3 n, vec3 r, float level_g,
                 bool glossy, vec3 ws_position) {
    vec3 pem_d = vec3(0.0), pem_g = vec3(0.0);
    if (in_pem1) {
        float layer = float(i - REGIONS_PER_TEXTURE);
        if (pem_diffuse) pem_d = textureLod(u_pem1, vec4(n, layer), u_diffuse_level).rgb;
        if (pem_glossy && glossy) pem_g = textureLod(u_pem1, vec4(r, layer), level_g).rgb;
    } else {
        if (pem_diffuse) pem_d = textureLod(u_pem0, vec4(n, float(i)), u_diffuse_level).rgb;
        if (pem_glossy && glossy) pem_g = textureLod(u_pem0, vec4(r, float(i)), level_g).rgb;
    }
    add_light(i, pem_d, pem_g, n, ws_position, pem_diffuse, pem_glossy, sharp);
}

void main() {
#ifdef LIGHTING_COMPUTE
    ivec2 px = ivec2(gl_GlobalInvocationID.xy);
    if (any(greaterThanEqual(px, imageSize(o_image)))) return;
    vec4 g_pos = texelFetch(u_g_position, px, 0);
    if (g_pos.w < 0.0) return;   // no surface: the depth test's job in the fragment pass
#else
    ivec2 px = ivec2(gl_FragCoord.xy);
    vec4 g_pos = texelFetch(u_g_position, px, 0);
#endif
    vec4 g_nrm = texelFetch(u_g_normal, px, 0);
    vec3 ws_position = g_pos.xyz;
    vec3 n = g_nrm.xyz;
    vec4 g_geo = texelFetch(u_g_geometric, px, 0);
    g_geometric_normal = g_geo.xyz;
    g_shadow_group = int(g_geo.w + 0.5);
    vec3 albedo = texelFetch(u_g_albedo, px, 0).rgb;
    vec2 material = vec2(g_pos.w, g_nrm.w);
    vec3 to_eye = normalize(u_camera_pos - ws_position);
    vec3 r = reflect(-to_eye, n);
    g_reflect = r;
    g_to_eye = to_eye;
#ifdef CONTACT_SHADOWS
    contact_sectors(ws_position, to_eye, g_geometric_normal, px);
#endif
    g_gloss = material.y;
    float specular = material.x;
    float level_g = gloss_level(material.y);

#if MODE == 4
    {
        // Baseline of the paper's introduction: the N lights used for shading as well as for
        // shadows, each a directional light carrying its region's energy (no PEMs).
        float s_phong = 1.0 / max(1.0 - material.y, 1e-4);   // Eq. 3, capped so g = 1 stays finite
        for (int i = 0; i < u_n_lights; ++i) {
            vec3 l = lights[i].dir_scale.xyz;
            vec3 e = (lights[i].shadow.y > 0.5 ? visibility(i, ws_position, n, true)
                                               : visibility(i, ws_position, n, false)) * lights[i].energy.rgb;
            g_diffuse += e * max(dot(n, l), 0.0) / PI;
            g_glossy += e * (s_phong + 1.0) / (2.0 * PI) * pow(max(dot(r, l), 0.0), s_phong);
        }
    }
#else
    bool glossy = specular > 0.0;
    g_has_glossy = glossy;
    // One loop per kind of light (see the top): the constants fold the choices away. Only the kinds
    // this variant can have are compiled: without diffuse PEMs (DIFFUSE_LIGHTS) none reads one, and
    // the ambient-occlusion modes read both PEMs of every light (renderer.py, light_kinds).
#define KIND_LOOP(K) for (int k = (K) == 0 ? 0 : u_kind_end[max((K) - 1, 0)]; k < u_kind_end[K]; ++k) shade_light(light_order[k], ((K) & 1) != 0, ((K) & 2) != 0, ((K) & 4) != 0, ((K) & 8) != 0, n, r, level_g, glossy, ws_position);
#if defined(DIFFUSE_LIGHTS)
    KIND_LOOP(0) KIND_LOOP(2) KIND_LOOP(4) KIND_LOOP(6)
#if TWO_PEM_TEXTURES
    KIND_LOOP(8) KIND_LOOP(10) KIND_LOOP(12) KIND_LOOP(14)
#endif
#elif MODE >= 2
    KIND_LOOP(3) KIND_LOOP(7)
#if TWO_PEM_TEXTURES
    KIND_LOOP(11) KIND_LOOP(15)
#endif
#else
    KIND_LOOP(0) KIND_LOOP(1) KIND_LOOP(2) KIND_LOOP(3) KIND_LOOP(4) KIND_LOOP(5) KIND_LOOP(6) KIND_LOOP(7)
#if TWO_PEM_TEXTURES
    KIND_LOOP(8) KIND_LOOP(9) KIND_LOOP(10) KIND_LOOP(11) KIND_LOOP(12) KIND_LOOP(13) KIND_LOOP(14) KIND_LOOP(15)
#endif
#endif
#ifndef DIFFUSE_LIGHTS
    g_diffuse /= textureLod(u_pem_norm, vec4(n, 0.0), u_diffuse_level).r;
#endif
    g_diffuse += max(g_diffuse_exact, vec3(0.0));
    if (glossy) g_glossy /= textureLod(u_pem_norm, vec4(r, 0.0), level_g).r;
    g_glossy += g_glossy_exact;
#endif
    if (MODE == 2 || MODE == 3) {
        vec3 ao = g_ao_rgb / max(g_ao_norm, vec3(1e-30));
        g_diffuse *= ao;
        g_glossy *= ao;
    }
    vec4 color = vec4(albedo * g_diffuse + specular * g_glossy, 1.0);
#ifdef LIGHTING_COMPUTE
    imageStore(o_image, px, color);
#else
    o_color = color;
#endif
}
