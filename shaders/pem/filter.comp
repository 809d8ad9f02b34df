// The normalized separable 5x5 low-pass filter applied after each 2x2 reduction (Knuth et al. 2014,
// sec. 3.2 and 4), evaluated as the 25-tap outer product so that taps beyond a face edge read the
// neighbouring face through resolve_texel (seamless; same result as renderer/lighting/pem_reference.py).
// Writes the float32 result for the next reduction and the scaled half-float texel of this level.
layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

#include "common/cube.glsl"
#include "pem/tiles.glsl"

layout(std430, binding = BUF_PEM_INV_SCALE) readonly buffer InvScale { float inv_scale[]; };
layout(std430, binding = BUF_PEM_REDUCED) readonly buffer Src { vec4 src[]; };        // (batch, 6, n, n), reduced
layout(std430, binding = BUF_PEM_FILTERED) writeonly buffer Dst { vec4 dst[]; };       // (batch, 6, n, n), filtered
layout(binding = IMG_PEM_OUT, rgba16f) writeonly uniform imageCubeArray o_pem;

uniform int u_n;
uniform int u_first_region;
uniform int u_texture_first_region;  // first region stored in the bound cube-map array
uniform float u_taps[5];
uniform bool u_store;                // false above the PEM set's base level: computed, not kept

void main() {
    ivec3 id = ivec3(gl_GlobalInvocationID);
    if (id.x >= u_n || id.y >= u_n) return;
    int face = id.z % 6;
    int base = id.z - face;            // 6 * (index of the region in the batch)
    vec4 acc = vec4(0.0);
    if (tile_is_live()) {
        for (int dy = -2; dy <= 2; ++dy) {
            for (int dx = -2; dx <= 2; ++dx) {
                float w = u_taps[dy + 2] * u_taps[dx + 2];
                if (w == 0.0) continue;
                ivec3 t = resolve_texel(face, id.y + dy, id.x + dx, u_n);
                acc += w * src[((base + t.x) * u_n + t.y) * u_n + t.z];
            }
        }
    }
    dst[(id.z * u_n + id.y) * u_n + id.x] = acc;
    if (!u_store) return;
    int region = u_first_region + id.z / 6;
    imageStore(o_pem, ivec3(id.x, id.y, 6 * (region - u_texture_first_region) + face), vec4(acc.rgb * inv_scale[region], 1.0));
}
