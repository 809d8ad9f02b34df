// Variance shadow maps, pass 1: first and second depth moments (Donnelly & Lauritzen 2006) of one
// shadow group's casters, into that group's run of layers (shadows/vsm.py). The nearest surface wins
// through MIN blending (moments of the nearest depth are the smallest because depth >= 0), which
// replaces a depth buffer that moderngl cannot attach in layered form.
in float v_depth;
out vec2 o_moments;

void main() {
    float z = clamp(v_depth, 0.0, 1.0);
    // Second moment with the derivative term of Donnelly & Lauritzen (sec. 3.1) against acne on slopes.
    float dx = dFdx(z), dy = dFdy(z);
    o_moments = vec2(z, z * z + 0.25 * (dx * dx + dy * dy));
}
