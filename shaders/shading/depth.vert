// Depth pre-pass: lays down the nearest surface so that the expensive shading pass runs once per
// pixel (with LEQUAL) instead of once per overlapping fragment.
invariant gl_Position;   // bit-identical depth to surface.vert
in vec3 in_position;
uniform mat4 u_view_proj;
void main() { gl_Position = u_view_proj * vec4(in_position, 1.0); }
