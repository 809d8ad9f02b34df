// Level 0 of the partial environment maps (PEMs) of a batch of regions (Knuth et al. 2014, sec. 4):
// a copy of the cube map in which every texel outside the region is black, scaled by the region's
// 1/scale so that half floats never overflow (the shading pass multiplies the scale back).
layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

layout(std430, binding = BUF_PEM_ENV) readonly buffer Env { vec4 env[]; };          // (6, n, n)
layout(std430, binding = BUF_PEM_LABELS) readonly buffer Labels { int labels[]; };     // (6, n, n)
layout(std430, binding = BUF_PEM_INV_SCALE) readonly buffer InvScale { float inv_scale[]; }; // (regions,)
layout(binding = IMG_PEM_OUT, rgba16f) writeonly uniform imageCubeArray o_pem;

uniform int u_n;
uniform int u_first_region;
uniform int u_texture_first_region;  // first region stored in the bound cube-map array

void main() {
    ivec3 id = ivec3(gl_GlobalInvocationID);
    if (id.x >= u_n || id.y >= u_n) return;
    int face = id.z % 6;
    int region = u_first_region + id.z / 6;
    int t = (face * u_n + id.y) * u_n + id.x;
    vec4 value = labels[t] == region ? vec4(env[t].rgb * inv_scale[region], 1.0) : vec4(0.0, 0.0, 0.0, 1.0);
    imageStore(o_pem, ivec3(id.x, id.y, 6 * (region - u_texture_first_region) + face), value);
}
