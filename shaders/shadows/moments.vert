// Variance shadow maps, pass 1: every light's view of the scene in one instanced draw; instance i
// renders into layer i of the moments texture array (gl_Layer from the vertex shader:
// ARB_shader_viewport_layer_array, so no geometry shader and no layered depth attachment).
#extension GL_ARB_shader_viewport_layer_array : require

#include "common/lights.glsl"
layout(std430, binding = 0) readonly buffer Lights { Light lights[]; };

in vec3 in_position;
uniform int u_first_light;   // first shadow-map layer of this batch
uniform int u_layer_offset;  // this draw's first layer within the batch (full-detail layers come first)
out float v_depth;

void main() {
    int local = u_layer_offset + gl_InstanceID;
    int layer = u_first_light + local;
    int i = shadow_lights[layer];
    vec4 p = lights[i].view_proj * vec4(in_position, 1.0);
    // A tiled light's layer shows one tile of its footprint, widened by its margin.
    float k = lights[i].shadow.y;
    int tile = layer - int(lights[i].shadow.x);
    vec2 t = vec2(float(tile % int(k)), float(tile / int(k)));
    p.xy = (p.xy * k - (2.0 * t + 1.0 - k)) / lights[i].shadow.z;
    gl_Layer = local;
    v_depth = p.z;                 // orthographic: w = 1, z already in [0, 1]
    gl_Position = vec4(p.xy, 0.0, 1.0);
}
