// Copies layers between moment arrays at layer offsets: a batch of blurred layers into the full
// array (when the light count exceeds one layered draw), and the still casters' layers into and out
// of their copy (shadows/vsm.py).
// MOMENT_FORMAT (a #define, shadows/vsm.py): rg32f for one shadow group, rgba32f for two.
layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;
layout(binding = 1, MOMENT_FORMAT) readonly uniform image2DArray u_src;
layout(binding = 2, MOMENT_FORMAT) writeonly uniform image2DArray o_dst;
uniform int u_first_layer;   // the destination's first layer
uniform int u_src_first;     // the source's first layer

void main() {
    ivec3 id = ivec3(gl_GlobalInvocationID);
    ivec2 size = imageSize(o_dst).xy;
    if (id.x >= size.x || id.y >= size.y) return;
    imageStore(o_dst, ivec3(id.xy, u_first_layer + id.z), imageLoad(u_src, ivec3(id.xy, u_src_first + id.z)));
}
