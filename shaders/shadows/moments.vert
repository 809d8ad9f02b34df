// Variance shadow maps, pass 1: every light's view of one shadow group's casters in one instanced
// draw; instance i renders into layer u_first_layer + i of the moments texture array (the group's run) (gl_Layer from the vertex shader:
// ARB_shader_viewport_layer_array, so no geometry shader and no layered depth attachment).
#extension GL_ARB_shader_viewport_layer_array : require

#include "common/lights.glsl"
layout(std430, binding = 0) readonly buffer Lights { Light lights[]; };

in vec3 in_position;
uniform int u_first_layer;   // the group's first layer (group x the lights with a map)
out float v_depth;

void main() {
    int i = shadow_lights[gl_InstanceID];
    vec4 p = lights[i].view_proj * vec4(in_position, 1.0);
    gl_Layer = u_first_layer + gl_InstanceID;
    v_depth = p.z;                 // orthographic: w = 1, z already in [0, 1]
    gl_Position = vec4(p.xy, 0.0, 1.0);
}
