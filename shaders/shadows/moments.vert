// Variance shadow maps, pass 1: every light's view of the scene in one instanced draw; instance i
// renders into layer i of the moments texture array (gl_Layer from the vertex shader:
// ARB_shader_viewport_layer_array, so no geometry shader and no layered depth attachment).
#extension GL_ARB_shader_viewport_layer_array : require

#include "common/lights.glsl"
layout(std430, binding = 0) readonly buffer Lights { Light lights[]; };

in vec3 in_position;
uniform int u_first_light;   // first shadow-map layer of this batch
// Which layers this draw fills (renderer.py, sharp_full_detail_deg): -1 all; 0 those of lights whose
// disc's sine is at most u_coarse_min_sin (drawn from the full meshes); 1 the others (from a proxy).
uniform int u_detail_pass;
uniform float u_coarse_min_sin;
out float v_depth;

void main() {
    int i = shadow_lights[u_first_light + gl_InstanceID];
    vec4 p = lights[i].view_proj * vec4(in_position, 1.0);
    gl_Layer = gl_InstanceID;
    if (u_detail_pass >= 0 && (lights[i].params.w > u_coarse_min_sin) != (u_detail_pass == 1)) {
        v_depth = 1.0;
        gl_Position = vec4(2.0, 2.0, 2.0, 1.0);   // outside the clip volume: the layer is another pass's
        return;
    }
    v_depth = p.z;                 // orthographic: w = 1, z already in [0, 1]
    gl_Position = vec4(p.xy, 0.0, 1.0);
}
