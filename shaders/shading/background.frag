// The environment map itself seen along each view ray, behind the scene: a cube with its MIP chain
// (renderer/shading/background.py). Four rays spread over the pixel, each read with trilinear
// filtering over its quarter of the footprint (bias -1): closer to the pixel's box than one lookup.
layout(binding = TEX_ENVIRONMENT) uniform samplerCube u_env;

uniform mat4 u_inv_view_proj;
in vec2 v_ndc;
out vec4 o_color;

vec3 view_ray(vec2 ndc) {
    vec4 a = u_inv_view_proj * vec4(ndc, -1.0, 1.0);
    vec4 b = u_inv_view_proj * vec4(ndc, 1.0, 1.0);
    return normalize(b.xyz / b.w - a.xyz / a.w);
}

void main() {
    vec2 px = vec2(dFdx(v_ndc.x), dFdy(v_ndc.y));   // one pixel in NDC
    vec3 c = vec3(0.0);
    for (int k = 0; k < 4; ++k) {
        vec2 offset = (vec2(float(k & 1), float(k >> 1)) - 0.5) * 0.5 * px;
        c += texture(u_env, view_ray(v_ndc + offset), -1.0).rgb;
    }
    o_color = vec4(0.25 * c, 0.0);
}
