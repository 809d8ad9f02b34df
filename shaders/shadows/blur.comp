// Variance shadow maps, pass 2: blur of the moments with one width per light. The width follows the
// angular size of the light's region (Knuth et al. 2014, sec. 4): large dim regions give soft
// shadows, small bright ones sharp shadows.
//
// The Gaussian of standard deviation sigma is approximated by three successive box filters of
// radius r with 3 * ((2r + 1)^2 - 1) / 12 = sigma^2 (central limit theorem; W. M. Wells, "Efficient
// synthesis of Gaussian filters by cascaded uniform filters", IEEE PAMI 1986). Each box is a running
// sum along a line, so the cost per texel does not grow with the width: one invocation per line.
// Run for axis (1, 0) then (0, 1), three times each.
// Layer k of a group's run (shadows/vsm.py) is light shadow_lights[k mod u_group_layers]'s map.
layout(local_size_x = 64, local_size_y = 1, local_size_z = 1) in;

#include "common/lights.glsl"
layout(std430, binding = BUF_LIGHTS) readonly buffer Lights { Light lights[]; };
layout(binding = IMG_SHADOW_SRC, rg32f) readonly uniform image2DArray u_src;
layout(binding = IMG_SHADOW_DST, rg32f) writeonly uniform image2DArray o_dst;

uniform ivec2 u_axis;          // (1, 0): filter along rows; (0, 1): along columns
uniform int u_group_layers;   // the lights with a map
uniform int u_max_radius;

void main() {
    int line = int(gl_GlobalInvocationID.x);
    int layer = int(gl_GlobalInvocationID.z);
    ivec2 size = imageSize(u_src).xy;
    int length = u_axis.x == 1 ? size.x : size.y;
    int lines = u_axis.x == 1 ? size.y : size.x;
    if (line >= lines) return;
    ivec2 ortho = ivec2(1, 1) - u_axis;
    ivec2 origin = line * ortho;

    float sigma = lights[shadow_lights[layer % u_group_layers]].params.x;
    int r = min(int(round(0.5 * (sqrt(4.0 * sigma * sigma + 1.0) - 1.0))), u_max_radius);
    // No blur for this light: leave its layer alone in every pass. The six passes ping-pong between
    // the two arrays and end where they started, so an untouched layer keeps its moments (copying
    // them six times cost most of the blur stage: at blur scale 0.1 about 3 of 4 lights have r = 0).
    if (r <= 0) return;
    // Clamp-to-edge running sum of width 2r + 1 (light-space borders hold empty, unoccluded texels).
    vec2 sum = vec2(0.0);
    for (int k = -r; k <= r; ++k) sum += imageLoad(u_src, ivec3(origin + clamp(k, 0, length - 1) * u_axis, layer)).xy;
    float inv_width = 1.0 / float(2 * r + 1);
    for (int i = 0; i < length; ++i) {
        imageStore(o_dst, ivec3(origin + i * u_axis, layer), vec4(sum * inv_width, 0.0, 0.0));
        int add = min(i + r + 1, length - 1);
        int sub = max(i - r, 0);
        sum += imageLoad(u_src, ivec3(origin + add * u_axis, layer)).xy - imageLoad(u_src, ivec3(origin + sub * u_axis, layer)).xy;
    }
}
