// The environment map itself seen along each view ray, behind the scene.
layout(binding = 2) uniform samplerCube u_env;

uniform mat4 u_inv_view_proj;
in vec2 v_ndc;
out vec4 o_color;

void main() {
    vec4 a = u_inv_view_proj * vec4(v_ndc, -1.0, 1.0);
    vec4 b = u_inv_view_proj * vec4(v_ndc, 1.0, 1.0);
    vec3 d = normalize(b.xyz / b.w - a.xyz / a.w);
    o_color = vec4(textureLod(u_env, d, 0.0).rgb, 0.0);
}
