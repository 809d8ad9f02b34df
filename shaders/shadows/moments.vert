// Variance shadow maps, pass 1: every light's view of one shadow group's casters in one instanced
// draw; instance i renders into layer u_first_layer + i of the moments texture array (the group's
// run; gl_Layer from the vertex shader: ARB_shader_viewport_layer_array, so no geometry shader and no
// layered depth attachment).
// Each layer's projection comes from a uniform block in layer order (shadows/vsm.py), not from the
// lights' storage buffer: llvmpipe's vertex stage (one thread) gathered the storage buffer's matrix
// per vertex at about twice the cost of the whole draw.
#extension GL_ARB_shader_viewport_layer_array : require

// LAYERS_PER_DRAW mat4 (16 KiB: the least GL_MAX_UNIFORM_BLOCK_SIZE GL allows); more layers take
// several draws, the block bound at each one's first.
layout(std140, binding = BUF_LAYER_PROJECTIONS) uniform LayerProjections { mat4 u_layer_view_proj[LAYERS_PER_DRAW]; };

in vec3 in_position;
uniform int u_first_layer;   // this draw's first layer (group x the lights with a map, + the draw's first light)
out float v_depth;

void main() {
    vec4 p = u_layer_view_proj[gl_InstanceID] * vec4(in_position, 1.0);
    gl_Layer = u_first_layer + gl_InstanceID;
    v_depth = p.z;                 // orthographic: w = 1, z already in [0, 1]
    gl_Position = vec4(p.xy, 0.0, 1.0);
}
