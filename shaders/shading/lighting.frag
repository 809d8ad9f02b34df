// Lighting pass of the deferred shading (one full-screen triangle; the geometry pass,
// gbuffer.frag, has written position, normals and material per pixel), Knuth et al. 2014 Eq. 5:
// c = sum_i VIS_i * PEM_i(dir, g).
// The PEMs hold solid-angle weighted chains A_i (renderer/lighting/pem_reference.py): a lookup is
// A_i(dir) / B(dir), and B, the same for every region, is read once per direction.
// Diffuse: PEM_i looked up along the normal at the calibrated s = 1 level, times the albedo.
// Glossy: PEM_i looked up along the reflection vector at the level calibrated for g, times the
// specular weight. VIS_i is the variance-shadow-map visibility of light i.
// PBR (a #define: the scene has a glTF metallic-roughness material): a pixel's glossy term is
// N_LOBES lobes, each a lookup along its own axis at its own level with its own weight, from Kautz
// and McCool's fitted tables (lobes.glsl); a Phong pixel's one lobe is the one above.
//
// MODE (a #define, one program per mode: llvmpipe runs both sides of uniform branches under a mask,
// so unused modes would cost time): MODE_FULL the full method, MODE_NO_OCCLUSION, MODE_AO_GREY,
// MODE_AO_COLOUR and MODE_MANY_LIGHTS the baseline (renderer/gpu/contract.py names them all). The
// three research modes' code is in shading/research.glsl, compiled into their variants alone.
//
// Lights come in kinds, for the same reason: which of its PEMs a light reads (diffuse, glossy: a small
// light's terms may be in closed form instead), which shadow-map array holds its map, and which PEM
// texture holds its region. The renderer sorts the lights by kind (light_order, u_kind_end) and each
// kind has a loop of its own in which those choices are constants, so that no light pays for the
// lookups and closed forms of another kind (renderer/plan.py, light_kinds).
#include "common/lights.glsl"

#ifdef LIGHTING_COMPUTE
// The same pass as a compute shader, one invocation per pixel (renderer.py, Renderer.lighting_pass):
// GPUs built for compute (an H100 rasterizes on a few of its multiprocessors) run it on all of them.
// Uncovered pixels (the geometry pass's position.w = -1) keep the background drawn before.
layout(local_size_x = 8, local_size_y = 8) in;
layout(rgba32f, binding = IMG_LIGHTING_OUT) writeonly uniform image2D o_image;
#else
// The full-screen triangle lies at the far plane and the depth test is GREATER against the geometry
// pass's depth: only covered pixels pass, and blocks with none are skipped before shading.
layout(early_fragment_tests) in;
#endif

// Per-light tables are uniform blocks where the driver's blocks hold them (renderer.py): llvmpipe
// loads a block's entry once for a block of pixels, a storage buffer's per pixel.
#ifdef LIGHTS_CAPACITY
// std140 lays Light out as std430 does.
layout(std140, binding = BUF_LIGHTS) uniform LightsBlock { Light lights[LIGHTS_CAPACITY]; };
#else
layout(std430, binding = BUF_LIGHTS) readonly buffer Lights { Light lights[]; };
#endif
layout(std430, binding = BUF_GLOSS_LEVELS) readonly buffer GlossLevels { float level_of_g[]; };  // GLOSS_TABLE_SIZE
// The lights by kind, four to an entry (a uniform block's ints are 16 bytes apart).
layout(std140, binding = BUF_LIGHT_ORDER) uniform LightOrder { ivec4 light_order4[MAX_LIGHTS / 4]; };
#define light_order(k) light_order4[(k) >> 2][(k) & 3]
layout(binding = TEX_PEM0) uniform samplerCubeArray u_pem0;         // layer i = region i < 192, scaled by 1/scale_i
layout(binding = TEX_PEM1) uniform samplerCubeArray u_pem1;         // layer i - 192 = region i >= 192
layout(binding = TEX_PEM_NORM) uniform samplerCubeArray u_pem_norm;     // layer 0: B = chain(w), the normalizer
layout(binding = TEX_MOMENTS) uniform sampler2DArray u_moments;        // blurred moments, layer shadow.x of light i
layout(binding = TEX_MOMENTS_SHARP) uniform sampler2DArray u_moments_sharp; // the small lights' (shadow.y = 1), larger maps
#ifdef PENUMBRA_BLOCKER
layout(binding = TEX_CASTERS) uniform sampler2DArray u_casters;        // the main maps' caster share per group, with MIPs
#endif
#ifdef ORACLE_VISIBILITY
// The error split's oracle (renderer/reference/visibility.py): VIS_i of every covered pixel from rays
// cast on the CPU, layer i = light i, instead of the shadow maps (and no contact search).
layout(binding = TEX_ORACLE) uniform sampler2DArray u_oracle_visibility;
#endif
layout(binding = TEX_G_POSITION) uniform sampler2D u_g_position;         // the geometry pass's targets (gbuffer.frag)
layout(binding = TEX_G_NORMAL) uniform sampler2D u_g_normal;
layout(binding = TEX_G_GEOMETRIC) uniform sampler2D u_g_geometric;
layout(binding = TEX_G_ALBEDO) uniform sampler2D u_g_albedo;
#ifdef PBR
layout(binding = TEX_G_PBR) uniform sampler2D u_g_pbr;             // metallic, roughness, sheen roughness, kind
                                                                    // (0: Phong; 1: isotropic; anisotropy.glsl)
#define N_LOBES (LOBES_GGX + LOBES_SHEEN)
#else
#define N_LOBES 1
#endif
// FOR_EACH_LOBE(F): F(0) F(1) ... F(N_LOBES - 1), the lobe loops written out: with a loop over the
// lobes' arrays (unrolled or not by the driver) llvmpipe kept them in memory, and a pixel of two
// lobes (GGX and sheen) shaded about a sixth slower than with the same code written out.
#if N_LOBES == 1
#define FOR_EACH_LOBE(F) F(0)
#elif N_LOBES == 2
#define FOR_EACH_LOBE(F) F(0) F(1)
#elif N_LOBES == 3
#define FOR_EACH_LOBE(F) F(0) F(1) F(2)
#elif N_LOBES == 4
#define FOR_EACH_LOBE(F) F(0) F(1) F(2) F(3)
#else
#error "FOR_EACH_LOBE writes out at most 4 lobes (the lobes setting's range: 1 or 2 per layer, two layers)"
#endif

uniform vec3 u_camera_pos;
uniform int u_n_lights;
// light_order[u_kind_end[k - 1] .. u_kind_end[k]) are the lights of kind k: bit 0 reads its diffuse
// PEM, bit 1 its glossy PEM, bit 2 its map is in the sharp array, bit 3 its region is in u_pem1.
uniform int u_kind_end[16];
uniform float u_diffuse_level;
uniform float u_min_sigma_texels;  // FrameSettings.min_sigma_texels: least deviation of the depths under a texel
uniform float u_bleed_reduction;   // Lauritzen's light-bleeding reduction: clip p_max below this
uniform float u_normal_offset_texels;  // the shadow lookup pushed off the surface along n, in the light's own texels

#ifndef LIGHTING_COMPUTE
out vec4 o_color;
#endif

const float PI = 3.14159265358979;

float linstep(float lo, float hi, float x) { return clamp((x - lo) / (hi - lo), 0.0, 1.0); }

vec3 g_geometric_normal = vec3(0.0, 0.0, 1.0);  // the triangle's plane, facing the camera
#include "shading/vsm.glsl"

#ifdef CONTACT_SHADOWS
#include "shading/contact.glsl"
#endif

float gloss_level(float g) {
    float x = clamp(g, 0.0, 1.0) * float(GLOSS_TABLE_SIZE - 1);
    int k = min(int(x), GLOSS_TABLE_SIZE - 2);
    return mix(level_of_g[k], level_of_g[k + 1], x - float(k));
}

// Accumulators of main(), shared with add_light() (GLSL has no closures).
ivec2 g_px = ivec2(0);                          // the pixel shaded
vec3 g_to_eye = vec3(0.0, 0.0, 1.0);            // unit, from the pixel's surface point to the eye
vec3 g_diffuse = vec3(0.0);
// The pixel's lobes: axis, PEM level, 1 / exponent (the closed forms' width) and weight (rgb), set by
// main() before the lights; their PEM terms and closed-form terms, summed over the lights.
vec3 g_lobe_axis[N_LOBES];
// The PEMs are in the map's own frame: a turned environment (FrameSettings.environment_rotation_deg)
// reads them through the inverse turn (renderer/lighting/pem.py, PEMSet.turned), the lights' directions
// being turned already. The pixel's lookup directions in that frame, made once before the light loops.
uniform mat3 u_env_from_world;
vec3 g_n_env;
vec3 g_lobe_axis_env[N_LOBES];
#ifdef SHADOW_CATCHER
// A shadow catcher (renderer.Background.SHADOW_CATCHER): the catcher mesh's pixels (its id) keep the
// diffuse light they would get with nothing in the way beside what they get, and show as black with
// alpha the share the other meshes take: 1 - shadowed / unshadowed, in luminance. What a matte floor
// shows; its own material is not drawn.
uniform float u_catcher_id;
bool g_catcher = false;
vec3 g_free_diffuse = vec3(0.0);
vec3 g_free_diffuse_exact = vec3(0.0);
#endif
#ifdef SHEETS
// Sheer and transmitting cloth (Material.alpha, Material.transmission), per mesh: entry id - 1 of the
// mesh's id in the geometric target's w (renderer.py, _sheets). A pixel's fibres reflect
// (1 - transmission) of their model's light and pass on transmission x tint of the light from behind
// the sheet (tint: the albedo, x (1 - metallic) for a physically based pixel): each light's PEM along
// -n at the diffuse level (or its closed form about -n), its visibility at the point pushed off to
// the sheet's other side (renderer/reference/montecarlo.py, _with_transmitted). The colour written is
// premultiplied by alpha, alpha the share of the pixel's ray the fibres stop (the layers behind are
// blended under it: renderer.py, _sheer_layers). The transmitted term is compiled in only where some
// mesh transmits (TRANSMISSION): llvmpipe would run its lookups for every pixel.
uniform vec2 u_sheets[MAX_SHEET_MESHES];
float g_transmission = 0.0;
vec3 g_transmitted = vec3(0.0);
vec3 g_transmitted_exact = vec3(0.0);
#endif
float g_lobe_level[N_LOBES];
float g_lobe_inv_s[N_LOBES];
vec3 g_lobe_weight[N_LOBES];
// A physically based pixel's BRDF is zero below the shading normal's horizon (brdf.py), and its lobes
// were fitted to that: each light's glossy terms keep the share of its disc above that plane. (The
// Phong model's lobes are not clipped by n: renderer/reference/montecarlo.py.)
bool g_clip_lobes = false;
vec3 g_glossy[N_LOBES];
vec3 g_glossy_exact[N_LOBES];

#include "shading/discs.glsl"
#ifdef PBR
#include "shading/lobes.glsl"
#endif
#include "shading/research.glsl"

// Light i's glossy terms, its visibility `vis`: from its PEM lookups (pem_g, still divided by the
// region's `scale`) or its disc in closed form, per lobe. A physically based pixel (g_clip_lobes): the
// light's part above the plane `p` (the horizon that cuts more of its disc), either from the exact BRDF
// over its disc (lobes.glsl, pbr_exact_light) or, per lobe, the lobe's own share of the disc above
// the plane (discs.glsl, lobe_share_above): a lobe's PEM term holds no light from below its own equator.
void add_glossy(int i, vec3 pem_g[N_LOBES], bool pem_glossy, float vis, float scale, bool small, vec3 p) {
    float x_h = -2.0;
#ifdef PBR
    if (g_clip_lobes) {
        if (pbr_exact_light(i, small, pem_glossy)) {
            g_pbr_exact += vis * pbr_from_light_above(i, p);
            return;
        }
        x_h = horizon_crossing(i, p);
    }
#endif
#define GLOSSY_LOBE(k) { \
        float share = x_h > -1.0 ? lobe_share_above(i, p, x_h, g_lobe_axis[k], g_lobe_inv_s[k]) : 1.0; \
        if (!pem_glossy || wide_lobe(i, g_lobe_inv_s[k])) { \
            if (g_has_glossy) g_glossy_exact[k] += (vis * share) * glossy_from_light(i, g_lobe_axis[k], g_lobe_inv_s[k]); \
        } else { \
            g_glossy[k] += (vis * share * scale) * pem_g[k]; \
        } \
    }
    FOR_EACH_LOBE(GLOSSY_LOBE)
#undef GLOSSY_LOBE
}

// Adds light i, given its PEM looked up along the normal (pem_d, diffuse level) and along each lobe's
// axis (pem_g, the lobe's level), all still divided by the region's scale.
// pem_diffuse / pem_glossy: the light's terms come from its PEMs (else in closed form); sharp: its map
// is in the sharp array. Constants of the caller's loop (see main()).
void add_light(int i, vec3 pem_d, vec3 pem_g[N_LOBES], vec3 n, vec3 ws_pos, bool pem_diffuse, bool pem_glossy,
               bool sharp, vec3 pem_t) {
    float scale = lights[i].dir_scale.w;
    pem_d *= scale;
    pem_t *= scale;
#if MODE == MODE_NO_OCCLUSION
    if (!pem_diffuse) g_diffuse_exact += diffuse_from_light(i, n);
    else g_diffuse += pem_d;
    add_glossy(i, pem_g, pem_glossy, 1.0, scale, lights[i].shadow.w > 0.5, n);
#ifdef TRANSMISSION
    if (g_transmission > 0.0) {   // the light behind the sheet, unshadowed
        float share_t = disc_share_above(i, -g_geometric_normal);
        if (pem_diffuse) g_transmitted += share_t * pem_t;
        else g_transmitted_exact += share_t * diffuse_from_light(i, -n);
    }
#endif
#elif MODE == MODE_FULL
#ifdef ORACLE_VISIBILITY
    float vis = texelFetch(u_oracle_visibility, ivec3(g_px, i), 0).r;
#else
    float vis = visibility(i, ws_pos, n, sharp);
#ifdef CONTACT_SHADOWS
    if (lights[i].shadow.x >= 0.0) vis = min(vis, contact_visibility(i, g_to_eye));
#endif
#endif
    // Light from below the surface's own plane (the triangle's, not the interpolated normal's) is
    // blocked by the surface for a closed body and by the body under a garment; a shadow map cannot
    // resolve it at the terminator, where the surface is its own occluder at grazing angles. Share of
    // the light's disc above that plane:
    float above = disc_share_above(i, g_geometric_normal);
    // Small lights (a sun): both terms (their terminator is sharp; a large region's share is soft
    // and its PEM's diffuse kernel spreads it anyway); large lights: the glossy term (the lobe's part
    // below the surface, which the reference's visibility removes and the PEM lookup along r does not).
    bool small = lights[i].shadow.w > 0.5;   // decided once, in renderer/shadows/lights.py
    float vis_d = small ? vis * above : vis;
    if (pem_diffuse) g_diffuse += vis_d * pem_d;
    else g_diffuse_exact += vis_d * diffuse_from_light(i, n);
#ifdef SHADOW_CATCHER
    if (g_catcher) {
        float free_d = small ? above : 1.0;
        if (pem_diffuse) g_free_diffuse += free_d * pem_d;
        else g_free_diffuse_exact += free_d * diffuse_from_light(i, n);
    }
#endif
    // A physically based pixel's glossy terms: the light's part above both planes, the shading
    // normal's and the surface's, from the one that cuts more of its disc (add_glossy).
    if (g_clip_lobes)
        add_glossy(i, pem_g, pem_glossy, vis, scale, small,
                   horizon_crossing(i, n) >= horizon_crossing(i, g_geometric_normal) ? n : g_geometric_normal);
    else
        add_glossy(i, pem_g, pem_glossy, vis * above, scale, small, n);
#ifdef TRANSMISSION
    if (g_transmission > 0.0) {
        // The light on the sheet's other side: its visibility there (the own group's lookup pushed
        // off along -n) and the share of its disc behind the sheet's plane (every light's: a region
        // whose centre lies in front reaches the -n lookup through the diffuse kernel alone, and the
        // rest of the garment hides its part behind).
        vec3 seen_side = g_geometric_normal;
        g_geometric_normal = -seen_side;
        float vis_t = visibility(i, ws_pos, -n, sharp);
        vis_t *= disc_share_above(i, -seen_side);
        g_geometric_normal = seen_side;
        if (pem_diffuse) g_transmitted += vis_t * pem_t;
        else g_transmitted_exact += vis_t * diffuse_from_light(i, -n);
    }
#endif
#elif MODE == MODE_AO_GREY || MODE == MODE_AO_COLOUR
    add_light_ao(i, pem_d, pem_g, n, ws_pos, sharp, scale);   // research.glsl
#endif
}

// One light of a kind: its PEM lookups (region i in u_pem0, or in u_pem1 when in_pem1), then add_light.
void shade_light(int i, bool pem_diffuse, bool pem_glossy, bool sharp, bool in_pem1, vec3 n, bool glossy,
                 vec3 ws_position) {
#if MODE == MODE_FULL
    // A light wholly below the surface's own plane and below the shading normal's horizon adds nothing
    // (add_light: its glossy terms and a small light's diffuse term keep the share above the plane,
    // zero; its closed-form diffuse term is zero below the horizon): its lookups, shadow map and
    // contact search are skipped. A diffuse PEM's kernel reaches below the horizon: those lights stay.
    if (!pem_diffuse) {
        vec3 l = lights[i].dir_scale.xyz;
        float sin_a = lights[i].params.w;
        bool behind = dot(g_geometric_normal, l) <= -sin_a && dot(n, l) <= -sin_a;
#ifdef TRANSMISSION
        behind = behind && g_transmission <= 0.0;
#endif
        if (behind) return;
    }
#endif
    vec3 pem_t = vec3(0.0);   // the diffuse PEM along -n (a transmitting pixel's)
    vec3 pem_d = vec3(0.0);
    vec3 pem_g[N_LOBES];
#define ZERO_LOBE(k) pem_g[k] = vec3(0.0);
    FOR_EACH_LOBE(ZERO_LOBE)
#undef ZERO_LOBE
#ifdef PBR
    // A light whose glossy terms come from the exact BRDF reads no glossy PEM.
    if (g_clip_lobes && pbr_exact_light(i, lights[i].shadow.w > 0.5, pem_glossy)) glossy = false;
#endif
    if (in_pem1) {
        float layer = float(i - REGIONS_PER_TEXTURE);
        if (pem_diffuse) pem_d = textureLod(u_pem1, vec4(g_n_env, layer), u_diffuse_level).rgb;
#ifdef TRANSMISSION
        if (pem_diffuse && g_transmission > 0.0) pem_t = textureLod(u_pem1, vec4(-g_n_env, layer), u_diffuse_level).rgb;
#endif
        if (pem_glossy && glossy) {
#define LOOKUP_LOBE(k) pem_g[k] = textureLod(u_pem1, vec4(g_lobe_axis_env[k], layer), g_lobe_level[k]).rgb;
            FOR_EACH_LOBE(LOOKUP_LOBE)
#undef LOOKUP_LOBE
        }
    } else {
        if (pem_diffuse) pem_d = textureLod(u_pem0, vec4(g_n_env, float(i)), u_diffuse_level).rgb;
#ifdef TRANSMISSION
        if (pem_diffuse && g_transmission > 0.0) pem_t = textureLod(u_pem0, vec4(-g_n_env, float(i)), u_diffuse_level).rgb;
#endif
        if (pem_glossy && glossy) {
#define LOOKUP_LOBE(k) pem_g[k] = textureLod(u_pem0, vec4(g_lobe_axis_env[k], float(i)), g_lobe_level[k]).rgb;
            FOR_EACH_LOBE(LOOKUP_LOBE)
#undef LOOKUP_LOBE
        }
    }
    add_light(i, pem_d, pem_g, n, ws_position, pem_diffuse, pem_glossy, sharp, pem_t);
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
    g_px = px;
    vec4 g_nrm = texelFetch(u_g_normal, px, 0);
    vec3 ws_position = g_pos.xyz;
    vec3 n = g_nrm.xyz;
    vec4 g_geo = texelFetch(u_g_geometric, px, 0);
    g_geometric_normal = g_geo.xyz;
    int geometric_w = int(g_geo.w + 0.5) % MESH_ID_STRIDE;   // the mesh's id above it: the id pass's
#ifdef SHADOW_CATCHER
    g_catcher = abs(floor((g_geo.w + 0.5) / float(MESH_ID_STRIDE)) - u_catcher_id) < 0.5;
#endif
#ifdef SHEETS
    int mesh_id = int(floor((g_geo.w + 0.5) / float(MESH_ID_STRIDE)));
    vec2 sheet = mesh_id >= 1 && mesh_id <= MAX_SHEET_MESHES ? u_sheets[mesh_id - 1] : vec2(1.0, 0.0);
    // An alpha map's texel: what it took away is packed below 1 in w (gbuffer.frag).
    sheet.x *= 1.0 - (g_geo.w - floor(g_geo.w + 0.5)) / ALPHA_MAP_FRACTION;
    g_transmission = sheet.y;
#endif
    g_convex_surface = geometric_w >= CONVEX_SURFACE;
    g_shadow_group = g_convex_surface ? geometric_w - CONVEX_SURFACE : geometric_w;
    vec4 g_alb = texelFetch(u_g_albedo, px, 0);
    vec3 albedo = g_alb.rgb;
    vec2 material = vec2(g_pos.w, g_nrm.w);
    vec3 to_eye = normalize(u_camera_pos - ws_position);
    vec3 r = reflect(-to_eye, n);
    g_to_eye = to_eye;
#ifdef CONTACT_SHADOWS
    contact_sectors(ws_position, to_eye, g_geometric_normal, px);
#endif
    // The pixel's lobes. A Phong pixel: one about r at the level calibrated for g, weight specular,
    // over the albedo's diffuse term.
#define START_LOBE(k) { \
        g_lobe_axis[k] = r; \
        g_lobe_level[k] = 0.0; \
        g_lobe_inv_s[k] = 1.0; \
        g_lobe_weight[k] = vec3(0.0); \
        g_glossy[k] = vec3(0.0); \
        g_glossy_exact[k] = vec3(0.0); \
    }
    FOR_EACH_LOBE(START_LOBE)
#undef START_LOBE
    vec3 diffuse_weight = albedo;
#ifdef TRANSMISSION
    vec3 transmitted_tint = albedo;
#endif
    g_lobe_level[0] = gloss_level(material.y);
    g_lobe_inv_s[0] = max(1.0 - material.y, 0.0);
    g_lobe_weight[0] = vec3(material.x);
    bool glossy = material.x > 0.0;
#ifdef PBR
    vec4 pbr = texelFetch(u_g_pbr, px, 0);
    if (pbr.w > 0.5) {
        // glTF metallic-roughness with sheen: albedo is the base colour; the sheen colour rides in the
        // targets' spare channels (gbuffer.frag). The normal faces the eye (lobes.glsl).
        n = facing_normal(n, to_eye);
#ifdef TRANSMISSION
        transmitted_tint = albedo * (1.0 - clamp(pbr.x, 0.0, 1.0));
#endif
        pbr_anisotropy(pbr.w, g_nrm.xyz, n);
        diffuse_weight = pbr_lobes(n, to_eye, albedo, pbr.x, pbr.y, vec3(material, g_alb.a), pbr.z);
        glossy = true;
        g_clip_lobes = true;
    }
#endif

    g_n_env = u_env_from_world * n;
#define ENV_AXIS(k) g_lobe_axis_env[k] = u_env_from_world * g_lobe_axis[k];
    FOR_EACH_LOBE(ENV_AXIS)
#undef ENV_AXIS

#if MODE == MODE_MANY_LIGHTS
    shade_many_lights(n, ws_position);   // research.glsl
#else
    g_has_glossy = glossy;
    // One loop per kind of light (see the top): the constants fold the choices away. Only the kinds
    // this variant can have are compiled: without diffuse PEMs (DIFFUSE_LIGHTS) none reads one, and
    // the ambient-occlusion modes read both PEMs of every light (renderer/plan.py, light_kinds).
#define KIND_LOOP(K) for (int k = (K) == 0 ? 0 : u_kind_end[max((K) - 1, 0)]; k < u_kind_end[K]; ++k) shade_light(light_order(k), ((K) & KIND_PEM_DIFFUSE) != 0, ((K) & KIND_PEM_GLOSSY) != 0, ((K) & KIND_SHARP) != 0, ((K) & KIND_SECOND_PEM) != 0, n, glossy, ws_position);
#if defined(DIFFUSE_LIGHTS)
    KIND_LOOP(0) KIND_LOOP(2) KIND_LOOP(4) KIND_LOOP(6)
#if TWO_PEM_TEXTURES
    KIND_LOOP(8) KIND_LOOP(10) KIND_LOOP(12) KIND_LOOP(14)
#endif
#elif MODE == MODE_AO_GREY || MODE == MODE_AO_COLOUR
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
    float diffuse_norm = textureLod(u_pem_norm, vec4(g_n_env, 0.0), u_diffuse_level).r;
    g_diffuse /= diffuse_norm;
#ifdef SHADOW_CATCHER
    g_free_diffuse /= diffuse_norm;
#endif
#ifdef TRANSMISSION
    if (g_transmission > 0.0) g_transmitted /= textureLod(u_pem_norm, vec4(-g_n_env, 0.0), u_diffuse_level).r;
#endif
#endif
    g_diffuse += max(g_diffuse_exact, vec3(0.0));
#define END_LOBE(k) { \
        if (glossy) g_glossy[k] /= textureLod(u_pem_norm, vec4(g_lobe_axis_env[k], 0.0), g_lobe_level[k]).r; \
        g_glossy[k] += g_glossy_exact[k]; \
    }
    FOR_EACH_LOBE(END_LOBE)
#undef END_LOBE
#endif
    vec3 glossy_sum = vec3(0.0);
#define SUM_LOBE(k) glossy_sum += g_lobe_weight[k] * g_glossy[k];
    FOR_EACH_LOBE(SUM_LOBE)
#undef SUM_LOBE
#if MODE == MODE_AO_GREY || MODE == MODE_AO_COLOUR
    vec3 ao = ambient_occlusion();   // research.glsl
    g_diffuse *= ao;
    glossy_sum *= ao;
#endif
#ifdef PBR
    glossy_sum += g_pbr_exact;
#endif
    vec4 color = vec4(diffuse_weight * g_diffuse + glossy_sum, 1.0);
#if defined(TRANSMISSION) && (MODE == MODE_FULL || MODE == MODE_NO_OCCLUSION)
    // (The research modes leave transmission out: their terms are the reflected light's alone.)
    color.rgb = (1.0 - g_transmission) * color.rgb
              + g_transmission * transmitted_tint * (g_transmitted + max(g_transmitted_exact, vec3(0.0)));
#endif
#ifdef SHEETS
    color *= clamp(sheet.x, 0.0, 1.0);
#endif
#ifdef SHADOW_CATCHER
    if (g_catcher) {
        const vec3 LUMINANCE = vec3(0.2126, 0.7152, 0.0722);
        float free_light = dot(g_free_diffuse + max(g_free_diffuse_exact, vec3(0.0)), LUMINANCE);
        float shadowed = dot(g_diffuse, LUMINANCE);
        color = vec4(0.0, 0.0, 0.0, free_light > 0.0 ? clamp(1.0 - shadowed / free_light, 0.0, 1.0) : 0.0);
    }
#endif
#ifdef LIGHTING_COMPUTE
    imageStore(o_image, px, color);
#else
    o_color = color;
#endif
}
