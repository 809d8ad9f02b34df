// Variance shadow maps, pass 1: first and second depth moments (Donnelly & Lauritzen 2006), per shadow
// group: xy for the casters of group 0, zw for those of group 1 (Scene: a garment and what it is
// worn on). The nearest surface of each group wins through MIN blending (moments of the nearest depth
// are the smallest because depth >= 0; the other group's pair is written as the cleared far plane),
// which replaces a depth buffer that moderngl cannot attach in layered form.
in float v_depth;
uniform int u_group;   // 0 or 1: which pair this caster's moments go to
out vec4 o_moments;

void main() {
    float z = clamp(v_depth, 0.0, 1.0);
    // Second moment with the derivative term of Donnelly & Lauritzen (sec. 3.1) against acne on slopes.
    float dx = dFdx(z), dy = dFdy(z);
    vec2 m = vec2(z, z * z + 0.25 * (dx * dx + dy * dy));
    o_moments = u_group == 0 ? vec4(m, 1.0, 1.0) : vec4(1.0, 1.0, m);
}
