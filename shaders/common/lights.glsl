// Per-light data shared by the shadow and shading passes; mirrored by renderer/shadows/lights.py
// (LIGHT_DTYPE), and a test checks that the two agree.
struct Light {
    mat4 view_proj;      // world -> light clip space (orthographic, depth in [0, 1])
    vec4 dir_scale;      // xyz: unit direction towards the region's energy centroid; w: PEM scale
    vec4 params;         // x: blur sigma (the light's own texels); y: one texel of its map in its depth
                         // units (the depth range is 1); z: solid angle (sr);
                         // w: sine of the light's angular radius (energy spread), for the horizon term
    vec4 energy;         // rgb: region energy (radiance x sr); a: 1 if its penumbra follows the blocker's
                         // distance (an area light's, FrameSettings.penumbra "blocker"), else 0
    vec4 shadow;         // x: shadow-map layer (-1: none); y: 1 if the map is in the sharp array (a
                         // small light's, small_light_scale times the size), else 0; z: one texel of
                         // its map in world units; w: 1 if the light is small (a sun: its disc's sine at
                         // most SMALL_LIGHT_MAX_SIN, renderer/shadows/lights.py), else 0
};

// Lights that have a shadow map, in layer order (layer k belongs to light shadow_lights[k]).
layout(std430, binding = BUF_SHADOW_LIGHTS) readonly buffer ShadowLights { int shadow_lights[]; };
