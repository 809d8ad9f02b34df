// Per-light data shared by the shadow and shading passes; mirrored by renderer/shadows/lights.py
// (LIGHT_DTYPE), and a test checks that the two agree.
struct Light {
    mat4 view_proj;      // world -> light clip space (orthographic, depth in [0, 1])
    vec4 dir_scale;      // xyz: unit direction towards the region's energy centroid; w: PEM scale
    vec4 params;         // x: blur sigma (the light's own texels); y: first shadow-map layer, -1 if
                         // unshadowed (= shadow.x); z: solid angle (sr);
                         // w: sine of the light's angular radius (energy spread), for the horizon term
    vec4 energy;         // rgb: region energy (radiance x sr); a: luminance energy
    vec4 shadow;         // x: first shadow-map layer (-1: none); y: tiles per side k (a small light's
                         // map is k x k layers, each a k-th of the footprint per axis); z: each tile's
                         // footprint widening (its margin, 1 when k = 1)
};

// Clip-space xy of the light's whole footprint -> the tile (tx, ty) that holds it and the point's
// clip-space xy within that tile's layer. Identity for k = 1.
vec2 tile_of(vec2 c, float k, out vec2 t) {
    t = clamp(floor((c * 0.5 + 0.5) * k), vec2(0.0), vec2(k - 1.0));
    return c * k - (2.0 * t + 1.0 - k);
}

// Lights that have a shadow map, in layer order (layer k belongs to light shadow_lights[k]).
layout(std430, binding = 2) readonly buffer ShadowLights { int shadow_lights[]; };
