// Contact-hardening penumbrae (FrameSettings.penumbra "blocker"): the share of each main-map texel
// that a caster covers, per shadow group, from the drawn moments. A texel no caster reached keeps the
// clear value (1, 1), the far plane; every caster lies nearer (the projection's depth range ends 1 %
// beyond the casters' box). Its MIP chain then gives each region's caster share, with which the
// blocker search leaves the empty texels out of the region's moments (shading/vsm.glsl).
// Layer k of the moments holds group 0's map of light k, layer u_group_layers + k group 1's.
layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;
layout(binding = IMG_SHADOW_SRC, rg32f) readonly uniform image2DArray u_moments;
layout(binding = IMG_SHADOW_DST, rg16f) writeonly uniform image2DArray o_casters;
uniform int u_groups;         // 1 or 2
uniform int u_group_layers;   // the lights with a map

void main() {
    ivec3 id = ivec3(gl_GlobalInvocationID);
    ivec2 size = imageSize(u_moments).xy;
    if (id.x >= size.x || id.y >= size.y) return;
    float m0 = imageLoad(u_moments, id).x;
    float m1 = u_groups > 1 ? imageLoad(u_moments, id + ivec3(0, 0, u_group_layers)).x : 1.0;
    imageStore(o_casters, id, vec4(m0 < 1.0 ? 1.0 : 0.0, m1 < 1.0 ? 1.0 : 0.0, 0.0, 0.0));
}
