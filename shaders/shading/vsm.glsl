// Variance shadow maps (lighting.frag's shadow term): Chebyshev's bound on each light's moments, two
// shadow groups, the bias in the map's own texels. Included by shading/lighting.frag after the lights,
// the moment textures and their uniforms.

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
