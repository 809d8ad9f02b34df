// Contact-hardening penumbrae (FrameSettings.penumbra "blocker"): the share of each main-map texel
// that a caster covers, per shadow group, from the drawn moments. A texel no caster reached keeps the
// clear value (1, 1), the far plane; every caster lies nearer (the projection's depth range ends 1 %
// beyond the casters' box). Its MIP chain then gives each region's caster share, with which the
// blocker search leaves the empty texels out of the region's moments (shading/vsm.glsl).
// MOMENT_FORMAT (a #define, shadows/vsm.py): rg32f for one shadow group, rgba32f for two.
layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;
layout(binding = 1, MOMENT_FORMAT) readonly uniform image2DArray u_moments;
layout(binding = 2, rg16f) writeonly uniform image2DArray o_casters;

void main() {
    ivec3 id = ivec3(gl_GlobalInvocationID);
    ivec2 size = imageSize(u_moments).xy;
    if (id.x >= size.x || id.y >= size.y) return;
    vec4 m = imageLoad(u_moments, id);
    imageStore(o_casters, id, vec4(m.x < 1.0 ? 1.0 : 0.0, m.z < 1.0 ? 1.0 : 0.0, 0.0, 0.0));
}
