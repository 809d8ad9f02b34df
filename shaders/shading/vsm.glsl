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
bool g_convex_surface = false;   // the receiver's mesh bounds a convex volume (gbuffer.frag)
uniform bool u_two_groups;   // the maps hold both groups' moments; else group 0's alone
// The moments of group g's map of light i are at layer shadow.x + g x the array's lights with a map
// (renderer/shadows/vsm.py): a layer index per pixel, no branch on the group.
uniform float u_group_layers;         // u_moments'
uniform float u_group_layers_sharp;   // u_moments_sharp's

// A light's blurred moments (group zw: 1, else 0) at uv and MIP level; outside the map nothing casts
// (it is fitted to the casters). Only the main maps carry a MIP chain (PENUMBRA_BLOCKER), read by the
// penumbrae alone: every other lookup reads level 0.
vec2 moments(vec2 uv, float layer, bool sharp, bool zw, float level) {
    if (any(lessThan(uv, vec2(0.0))) || any(greaterThan(uv, vec2(1.0)))) return vec2(1.0);
    float group = zw ? 1.0 : 0.0;
    return sharp ? textureLod(u_moments_sharp, vec3(uv, layer + group * u_group_layers_sharp), level).xy
                 : textureLod(u_moments, vec3(uv, layer + group * u_group_layers), level).xy;
}

#ifdef SHEETS
// Each group's casters' alpha (Material.alpha; renderer/scene.py, Scene.group_alpha): sheer cloth is
// drawn into its maps as if opaque, and stops only that share of the light it is found to block (one
// sheet crossed; renderer/reference/montecarlo.py multiplies 1 - alpha per sheet crossed).
uniform vec2 u_group_alpha;
float through(float v, bool zw) { return 1.0 - (zw ? u_group_alpha.y : u_group_alpha.x) * (1.0 - v); }
#else
float through(float v, bool zw) { return v; }
#endif

// Chebyshev's visibility of one shadow group's pair (zw: group 1's) at receiver depth t.
float group_visibility(vec2 uv, float layer, bool sharp, bool zw, float t, float least_variance) {
    return through(chebyshev(moments(uv, layer, sharp, zw, 0.0), t, least_variance), zw);
}

#ifdef PENUMBRA_BLOCKER
// Contact-hardening penumbrae (percentage-closer soft shadows, Fernando 2005, on variance maps as in
// Yang et al. 2010, "Variance soft shadow mapping"), for the main maps' lights. A disc of angular
// radius theta seen past a blocker at light depth z_b from a receiver at t is cut over a radius
// (t - z_b) tan(theta): `spread` is tan(theta) over one texel's depth, so that this radius in texels
// is (t - z_b) * spread. The blocker search reads the widest region a blocker could shadow from (one
// at the casters' nearest depth, 0). Its empty texels (the far plane, no caster) are taken out of its
// mean depth (u_casters: the share a caster covers): the blockers' depth is the mean of the casters'.
// (Chebyshev's bound on the share beyond t, as Yang et al. estimate it, is an upper bound: it put
// the blockers nearer than they are and washed a sphere's umbra out on a floor.)
// The moments are then averaged over the penumbra from the map's MIP chain: a bilinear lookup at
// level L weighs a box of 2^L texels by a tent as wide, a deviation of 2^L / 2 per axis, which a disc
// of radius r has at 2^L = r (trilinear between levels).
float soft_visibility(vec2 uv, float layer, bool zw, float t, float least_variance, float spread) {
    float top = float(textureQueryLevels(u_moments) - 1);
    float search = clamp(log2(max(t * spread, 1.0)), 0.0, top);
    float mean = moments(uv, layer, false, zw, search).x;
    vec2 share = textureLod(u_casters, vec3(clamp(uv, 0.0, 1.0), layer), search).xy;
    float c = zw ? share.y : share.x;
    // The casters' own mean depth, an empty texel being (1, 1): the blockers' depth where they all lie
    // nearer than t (those of the other group); the receiver's own surface, in its own group's map at
    // about t, draws it towards t (a sharper penumbra: the fixed maps' own).
    float blocker = c > 1e-3 ? (mean - (1.0 - c)) / c : 1.0;
    float level = t > blocker ? clamp(log2(max((t - max(blocker, 0.0)) * spread, 1.0)), 0.0, top) : 0.0;
    // The same split at the penumbra's width: an empty texel is lit (the far plane lies beyond every
    // receiver), so the region's visibility is its empty share plus its casters' share times
    // Chebyshev's bound on the casters' own moments. On the moments as drawn, empty texels at 1 beside
    // blockers make a variance so large that the bound lets most of the light through an umbra.
    vec2 mf = moments(uv, layer, false, zw, level);
    vec2 shares = textureLod(u_casters, vec3(clamp(uv, 0.0, 1.0), layer), level).xy;
    float cf = zw ? shares.y : shares.x;
    if (cf <= 1e-3) return 1.0;
    vec2 mcf = (mf - (1.0 - cf)) / cf;
    return through((1.0 - cf) + cf * chebyshev(mcf, t, least_variance), zw);
}
#endif

// Whether the receiver's own group judges light i. On a convex surface (a ball), from a direction
// below the triangle's plane the map sees only the surface's own far side in front of the point, an
// occlusion that the terms' horizon already removes (the closed forms are clipped there, the glossy
// terms keep the disc's share above the plane): judged again, a region that straddles the plane would
// be lit all or nothing by where its centre falls, so its part above the plane is judged by the other
// group alone, as the oracle (renderer/reference/visibility.py) counts only the rays above the plane
// (white furnace at 6 lights: 4.4 % dark, its worst pixel 15 %, judged by the own group; as the lights
// alone without: tests/test_render.py). Any other surface sees other parts of itself there too (a leg
// beside a leg, the inside of a skirt), which do block the region's part above the plane: its own group
// judges every light (judged by the other group alone, the broad benchmark's error rose on nearly every
// scene, the dresses' most: docs/broad/own-group-skip-256.md against docs/broad/broad-256.md).
bool own_counts(int i) {
    return !g_convex_surface || dot(g_geometric_normal, lights[i].dir_scale.xyz) >= 0.0;
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
    vec2 uv = p.xy * 0.5 + 0.5, uv0 = p0.xy * 0.5 + 0.5;
#ifdef PENUMBRA_BLOCKER
    if (!sharp && lights[i].energy.a > 0.5) {
        // tan(theta) from the light's sine (params.w), theta at most 60 degrees as the paper's blur.
        float s = min(lights[i].params.w, 0.8660254);
        float spread = s / sqrt(1.0 - s * s) / lights[i].params.y;
        if (receiver_only) {
            float v = soft_visibility(uv0, layer, false, t0, 1e-7, spread);
            return u_two_groups ? min(v, soft_visibility(uv0, layer, true, t0, 1e-7, spread)) : v;
        }
        float floor_sigma = u_min_sigma_texels * lights[i].params.y;
        float own = own_counts(i) ? soft_visibility(uv, layer, g_shadow_group != 0, t,
                                                    max(floor_sigma * floor_sigma, 1e-7), spread) : 1.0;
        if (!u_two_groups) return own;
        return min(own, soft_visibility(uv0, layer, g_shadow_group == 0, t0, 1e-7, spread));
    }
#endif
    if (receiver_only) {
        float v = group_visibility(uv0, layer, sharp, false, t0, 1e-7);
        return u_two_groups ? min(v, group_visibility(uv0, layer, sharp, true, t0, 1e-7)) : v;
    }
    // The depths under one texel spread by about a texel where the surface slopes: a floor on the
    // deviation, in the light's own texels, keeps a surface from shadowing itself.
    float floor_sigma = u_min_sigma_texels * lights[i].params.y;
    // 1e-7: float32's cancellation in m.y - m.x^2 (depths in [0, 1]), the floor when the knob is 0.
    float own = own_counts(i) ? group_visibility(uv, layer, sharp, g_shadow_group != 0, t,
                                                 max(floor_sigma * floor_sigma, 1e-7)) : 1.0;
    if (!u_two_groups) return own;
    return min(own, group_visibility(uv0, layer, sharp, g_shadow_group == 0, t0, 1e-7));
}
