// Geometry pass of the deferred shading: what the lighting pass (lighting.frag) needs per pixel.
// Lighting runs once per covered pixel afterwards, however small the triangles: shading in the
// geometry pass itself ran the whole light loop for every 2x2 quad (every 4x4 block on llvmpipe) a
// triangle touches, several times per pixel on a garment whose triangles cover a pixel or two.
in vec3 v_ws_position;
in vec3 v_ws_normal;
in vec3 v_albedo;
in vec2 v_material;
in vec2 v_uv;
#ifdef PBR
// A scene with a physically based material (Material.model "pbr"): its parameters in a fifth target,
// its sheen colour in the spare channels of the others (lighting.frag reads them back).
in vec4 v_pbr;
in vec3 v_sheen;
// metallic, roughness, sheen roughness, and in w: 0 Phong, 1 isotropic, or an anisotropic GGX's
// strength and direction packed as 2 + q_a + 256 q_phi (anisotropy_code; lobes.glsl unpacks it)
layout(location = 4) out vec4 o_pbr;
layout(binding = TEX_SHEEN_MAP) uniform sampler2D u_sheen_map;    // rgb multiplies the sheen colour, a its roughness
uniform bool u_use_sheen_map;
uniform mat3x2 u_sheen_placement;
uniform float u_anisotropy_rotation;   // radians, counter-clockwise about n from growing u towards growing v
#include "shading/anisotropy.glsl"
#endif

layout(binding = TEX_ALBEDO_MAP) uniform sampler2D u_albedo_map;   // multiplies the vertex albedo
layout(binding = TEX_GLOSS_MAP) uniform sampler2D u_gloss_map;    // (specular, glossiness), replaces the vertex values
layout(binding = TEX_NORMAL_MAP) uniform sampler2D u_normal_map;   // tangent-space normals (Material.normal_map)
uniform float u_normal_scale;                          // its x and y scale; 0: no normal map
// Each map's placement: the affine map from the mesh's UVs to its own (TextureSet.placement: a
// fabric's textures at their physical size and rotation); the identity for a glTF file's.
uniform mat3x2 u_albedo_placement;
uniform mat3x2 u_second_placement;
uniform mat3x2 u_normal_placement;
uniform bool u_use_albedo_map;
uniform bool u_use_gloss_map;
// A sheer fabric's alpha map (TextureSet.alpha_map): the share of its texel it takes away, packed
// below 1 into the geometric target's w (ALPHA_MAP_FRACTION; lighting.frag multiplies the mesh's alpha).
layout(binding = TEX_ALPHA_MAP) uniform sampler2D u_alpha_map;
uniform bool u_use_alpha_map;
uniform mat3x2 u_alpha_placement;
uniform vec3 u_camera_pos;
uniform float u_shadow_group;   // the mesh's shadow group (renderer/scene.py): 0, 1, or 2 (casts nothing)
uniform float u_mesh_id;        // the mesh's place in the scene plus one (the id pass: renderer/aovs.py)
uniform bool u_convex_surface;  // the mesh bounds a convex volume (renderer/scene.py, SceneMesh.convex)

#ifdef PEEL
// A layer behind sheer cloth (renderer.py, _sheer_layers): the nearest surface behind the last layer
// drawn (its depth in u_peel_depth) where that layer let light through (the image so far is not yet
// opaque there); nothing elsewhere.
layout(binding = TEX_PEEL_DEPTH) uniform sampler2D u_peel_depth;
layout(binding = TEX_PEEL_OPACITY) uniform sampler2D u_peel_opacity;
#endif

layout(location = 0) out vec4 o_position;   // xyz: world position; w: specular weight (>= 0; -1: no surface)
layout(location = 1) out vec4 o_normal;     // xyz: shading normal, turned to the seen side; w: glossiness g
layout(location = 2) out vec4 o_geometric;  // xyz: the triangle's own plane normal, facing the camera; w: shadow
                                            // group, + CONVEX_SURFACE on a convex surface, + MESH_ID_STRIDE x id
layout(location = 3) out vec4 o_albedo;     // rgb: diffuse reflectance; a: 1 (covered)

// A material map's MIP level from the area of the pixel's footprint in its texels (the square root
// of the UV Jacobian's determinant): one trilinear lookup whose filter is as wide as a square of the
// footprint's area. GL's own level follows the footprint's longest side, which greys out a print seen
// obliquely (a pixel's area in the reference is a box); anisotropic filtering would follow the
// footprint, at a cost llvmpipe cannot pay for a finely repeating weave (its geometry pass 11 -> 480 ms).
// Called in uniform control flow (derivatives).
float area_lod(vec2 uv, ivec2 size) {
    vec2 dx = dFdx(uv) * vec2(size), dy = dFdy(uv) * vec2(size);
    return 0.5 * log2(max(abs(dx.x * dy.y - dx.y * dy.x), 1e-20));
}

void main() {
    vec3 n = normalize(v_ws_normal);
    vec3 to_eye = normalize(u_camera_pos - v_ws_position);
    // Screen derivatives outside the branches that depend on the pixel (they are undefined in
    // non-uniform control flow).
    vec3 dp1 = dFdx(v_ws_position), dp2 = dFdy(v_ws_position);
    vec2 duv1_mesh = dFdx(v_uv), duv2_mesh = dFdy(v_uv);
    // Degenerate derivatives (a triangle seen edge-on, underflow): fall back to the shading normal.
    vec3 c = cross(dp1, dp2);
    float c2 = dot(c, c);
    vec3 geometric = c2 > 1e-30 ? c * inversesqrt(c2) : n;
    if (dot(geometric, to_eye) < 0.0) geometric = -geometric;
    // Cloth is two-sided: shade the side of the sheet the camera sees, which the triangle's plane
    // decides. Where the interpolated normal leans across that plane (a fold seen from inside, a
    // grazing silhouette), it is turned to the seen side even if it then faces slightly away.
    if (dot(n, geometric) < 0.0) n = -n;
    if (u_normal_scale > 0.0) {
        // The tangent frame from the surface gradients of u and v (Schüler, "Normal Mapping Without
        // Precomputed Tangents", 2013): T = grad u, B = grad v in the plane of n, scaled by the larger;
        // renderer/reference/montecarlo.py builds the same frame from the triangle's edges.
        // The map's own UVs: its frame follows them (a rotated or mirrored placement turns it too).
        vec2 uv_n = u_normal_placement * vec3(v_uv, 1.0);
        vec2 duv1 = dFdx(uv_n), duv2 = dFdy(uv_n);
        float lod_n = area_lod(uv_n, textureSize(u_normal_map, 0));
        vec3 dp2perp = cross(dp2, n), dp1perp = cross(n, dp1);
        vec3 t = dp2perp * duv1.x + dp1perp * duv2.x;
        vec3 b = dp2perp * duv1.y + dp1perp * duv2.y;
        float det = dot(n, cross(dp1, dp2));
        float m = max(dot(t, t), dot(b, b));
        if (m > 1e-30) {
            float s = (det < 0.0 ? -1.0 : 1.0) * inversesqrt(m);
            vec3 tn = textureLod(u_normal_map, uv_n, lod_n).rgb * 2.0 - 1.0;
            vec3 mapped = normalize(s * (t * (tn.x * u_normal_scale) + b * (tn.y * u_normal_scale)) + n * tn.z);
            n = dot(mapped, geometric) < 0.0 ? -mapped : mapped;
        }
    }
    vec2 uv_second = u_second_placement * vec3(v_uv, 1.0);
    vec2 uv_albedo = u_albedo_placement * vec3(v_uv, 1.0);
    float lod_second = area_lod(uv_second, textureSize(u_gloss_map, 0));
    vec3 albedo = u_use_albedo_map ? v_albedo * textureLod(u_albedo_map, uv_albedo,
                                                           area_lod(uv_albedo, textureSize(u_albedo_map, 0))).rgb
                                   : v_albedo;
    vec2 material = u_use_gloss_map ? textureLod(u_gloss_map, uv_second, lod_second).rg : v_material;
    o_position = vec4(v_ws_position, material.x);
    o_normal = vec4(n, material.y);
    o_geometric = vec4(geometric, u_shadow_group + (u_convex_surface ? float(CONVEX_SURFACE) : 0.0)
                                  + float(MESH_ID_STRIDE) * u_mesh_id);
    vec2 uv_alpha = u_alpha_placement * vec3(v_uv, 1.0);
    float lod_alpha = area_lod(uv_alpha, textureSize(u_alpha_map, 0));
    if (u_use_alpha_map)
        o_geometric.w += ALPHA_MAP_FRACTION * (1.0 - clamp(textureLod(u_alpha_map, uv_alpha, lod_alpha).r, 0.0, 1.0));
    o_albedo = vec4(albedo, 1.0);
#ifdef PBR
    // A pbr mesh's second map is glTF's metallic-roughness texture: it multiplies the two values.
    vec2 mr = u_use_gloss_map ? textureLod(u_gloss_map, uv_second, lod_second).rg : vec2(1.0);
    // KHR_materials_sheen's textures multiply the sheen colour and roughness.
    vec2 uv_sheen = u_sheen_placement * vec3(v_uv, 1.0);
    vec4 sheen = u_use_sheen_map ? textureLod(u_sheen_map, uv_sheen, area_lod(uv_sheen, textureSize(u_sheen_map, 0)))
                                 : vec4(1.0);
    float kind = 1.0;
    float anisotropy = clamp(v_pbr.w - 1.0, 0.0, 1.0);
    if (anisotropy > 0.5 / 255.0)
        kind = anisotropy_code(anisotropy, anisotropy_direction(n, dp1, dp2, duv1_mesh, duv2_mesh,
                                                                 u_anisotropy_rotation), n);
    o_pbr = v_pbr.w > 0.5 ? vec4(v_pbr.xy * mr, v_pbr.z * sheen.a, kind) : vec4(0.0);
    if (v_pbr.w > 0.5) {
        vec3 sheen_colour = v_sheen * sheen.rgb;
        o_position.w = sheen_colour.r;   // >= 0, so "covered" still reads from w (-1: no surface)
        o_normal.w = sheen_colour.g;
        o_albedo.a = sheen_colour.b;
    }
#endif
#ifdef PEEL
    // At the end: the derivatives above are taken with every fragment of the quad alive. The depth
    // buffer holds 24 bits or more: 2^-20 keeps the last layer's own surface out.
    ivec2 px = ivec2(gl_FragCoord.xy);
    if (gl_FragCoord.z <= texelFetch(u_peel_depth, px, 0).r + 1.0 / 1048576.0
        || texelFetch(u_peel_opacity, px, 0).a >= 0.999) discard;
#endif
}
