// Anti-aliasing's coverage pass (renderer.py, _coverage_pass): the surfaces' depth at every sample of
// a multisampled target, positions alone, with the geometry pass's projection (the same depths).
in vec3 in_position;   // world space
uniform mat4 u_view_proj;

void main() {
    gl_Position = u_view_proj * vec4(in_position, 1.0);
}
