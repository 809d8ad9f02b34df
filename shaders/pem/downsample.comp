// The 2x2 mean of MIP mapping (Knuth et al. 2014, Fig. 2: "shrink"), for a batch of regions.
// FROM_ENV: the source is level 0, the masked environment map, read directly from the map and its
// region labels so that level 0 never has to be stored in float32 for every region.
layout(local_size_x = 8, local_size_y = 8, local_size_z = 1) in;

#ifdef FROM_ENV
layout(std430, binding = BUF_PEM_ENV) readonly buffer Env { vec4 env[]; };
layout(std430, binding = BUF_PEM_LABELS) readonly buffer Labels { int labels[]; };
#else
layout(std430, binding = BUF_PEM_FILTERED) readonly buffer Src { vec4 src[]; };        // (batch, 6, 2n, 2n)
#endif
#include "pem/tiles.glsl"

layout(std430, binding = BUF_PEM_REDUCED) writeonly buffer Dst { vec4 dst[]; };       // (batch, 6, n, n)

uniform int u_n;             // size of the destination level
uniform int u_first_region;

vec4 fetch(int layer, int row, int col) {
    int n2 = 2 * u_n;
#ifdef FROM_ENV
    int face = layer % 6;
    int t = (face * n2 + row) * n2 + col;
    return labels[t] == u_first_region + layer / 6 ? env[t] : vec4(0.0);
#else
    return src[(layer * n2 + row) * n2 + col];
#endif
}

void main() {
    ivec3 id = ivec3(gl_GlobalInvocationID);
    if (id.x >= u_n || id.y >= u_n) return;
    int r = 2 * id.y, c = 2 * id.x;
    vec4 m = vec4(0.0);
    if (tile_is_live()) {
        m = 0.25 * (fetch(id.z, r, c) + fetch(id.z, r, c + 1) + fetch(id.z, r + 1, c) + fetch(id.z, r + 1, c + 1));
    }
    dst[(id.z * u_n + id.y) * u_n + id.x] = m;
}
