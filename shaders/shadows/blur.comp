// Variance shadow maps, pass 2: a separable Gaussian blur of the moments, one width per light.
// The width follows the angular size of the light's region (Knuth et al. 2014, sec. 4): large dim
// regions give soft shadows, small bright ones sharp shadows. Run twice: horizontal, then vertical.
layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

#include "common/lights.glsl"
layout(std430, binding = 0) readonly buffer Lights { Light lights[]; };
layout(binding = 1, rg32f) readonly uniform image2DArray u_src;
layout(binding = 2, rg32f) writeonly uniform image2DArray o_dst;

uniform ivec2 u_axis;          // (1, 0) horizontal or (0, 1) vertical
uniform int u_first_light;
uniform int u_max_radius;      // taps per side, caps the cost of very large regions

void main() {
    ivec3 id = ivec3(gl_GlobalInvocationID);
    ivec2 size = imageSize(u_src).xy;
    if (id.x >= size.x || id.y >= size.y) return;
    float sigma = lights[u_first_light + id.z].params.x;
    vec2 acc = vec2(0.0);
    if (sigma < 0.3) {
        acc = imageLoad(u_src, id).xy;
    } else {
        int radius = min(int(ceil(3.0 * sigma)), u_max_radius);
        float wsum = 0.0;
        for (int k = -radius; k <= radius; ++k) {
            ivec2 q = clamp(id.xy + k * u_axis, ivec2(0), size - 1);
            float w = exp(-0.5 * float(k * k) / (sigma * sigma));
            acc += w * imageLoad(u_src, ivec3(q, id.z)).xy;
            wsum += w;
        }
        acc /= wsum;
    }
    imageStore(o_dst, id, vec4(acc, 0.0, 0.0));
}
