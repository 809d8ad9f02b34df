// Test probe: copies every field of `struct Light` as GLSL sees it, so a test can check that
// renderer/shadows/lights.py (LIGHT_DTYPE) lays the struct out as std430 does.
layout(local_size_x = 1) in;
#include "common/lights.glsl"
layout(std430, binding = BUF_PROBE_LIGHTS) readonly buffer Lights { Light lights[]; };
layout(std430, binding = BUF_PROBE_OUT) writeonly buffer Out { vec4 o[]; };   // 8 vec4 per light

void main() {
    int i = int(gl_GlobalInvocationID.x);
    Light l = lights[i];
    for (int c = 0; c < 4; ++c) o[8 * i + c] = l.view_proj[c];
    o[8 * i + 4] = l.dir_scale;
    o[8 * i + 5] = l.params;
    o[8 * i + 6] = l.energy;
    o[8 * i + 7] = l.shadow;
}
