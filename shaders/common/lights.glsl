// Per-light data shared by the shadow and shading passes; mirrored by renderer/shadows/lights.py
// (LIGHT_DTYPE), and a test checks that the two agree.
struct Light {
    mat4 view_proj;      // world -> light clip space (orthographic, depth in [0, 1])
    vec4 dir_scale;      // xyz: unit direction towards the region's energy centroid; w: PEM scale
    vec4 params;         // x: blur sigma (texels); y: 1 if the light has a shadow map; z: solid angle (sr)
    vec4 energy;         // rgb: region energy (radiance x sr); a: luminance energy
};
