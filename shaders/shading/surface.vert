// Geometry pass: world-space position, normal and material per vertex (to gbuffer.frag).
in vec3 in_position;     // world space
in vec3 in_normal;       // world space, unit length
in vec3 in_albedo;       // diffuse reflectance, linear RGB
in vec2 in_material;     // x: specular weight, y: glossiness g in [0, 1]
in vec2 in_uv;           // texture coordinates of the material maps
#ifdef PBR
in vec4 in_pbr;          // metallic, roughness, sheen roughness, 1 (0: a Phong material)
in vec3 in_sheen;        // sheen colour, linear RGB
out vec4 v_pbr;
out vec3 v_sheen;
#endif

uniform mat4 u_view_proj;

out vec3 v_ws_position;
out vec3 v_ws_normal;
out vec3 v_albedo;
out vec2 v_material;
out vec2 v_uv;

void main() {
    v_ws_position = in_position;
    v_ws_normal = in_normal;
    v_albedo = in_albedo;
    v_material = in_material;
    v_uv = in_uv;
#ifdef PBR
    v_pbr = in_pbr;
    v_sheen = in_sheen;
#endif
    gl_Position = u_view_proj * vec4(in_position, 1.0);
}
