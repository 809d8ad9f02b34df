// An anisotropic GGX pixel (Material.anisotropy): the direction its highlight stretches along and its
// strength, made in the geometry pass (gbuffer.frag) and packed into the w of its physically based
// target as 2 + q_a + 256 q_phi, an integer below 2^18 that a 32-bit float holds exactly (0: Phong,
// 1: isotropic); the lighting pass unpacks it (lobes.glsl). renderer/reference/montecarlo.py
// (anisotropy_direction) makes the same direction.

const float ANISOTROPY_ANGLES = 1024.0;   // steps of the direction's angle: 0.35 degrees
const float ANISOTROPY_TWO_PI = 6.28318530717959;

// The frame a direction's angle is packed in: a function of the normal alone (Duff et al. 2017,
// "Building an orthonormal basis, revisited"), so that the lighting pass rebuilds it from the normal
// it reads.
void anisotropy_basis(vec3 n, out vec3 t0, out vec3 b0) {
    float s = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (s + n.z);
    float b = n.x * n.y * a;
    t0 = vec3(1.0 + s * n.x * n.x * a, s * b, -s * n.x);
    b0 = vec3(b, s + n.y * n.y * a, -n.y);
}

// The direction: the surface gradient of u in the plane of n (the normal map's frame, from the screen
// derivatives dp and duv of the mesh's own UVs), turned by `rotation` radians about n from growing u
// towards growing v. Where u has no gradient (a mesh without UVs): the world's up axis in the plane
// (the x axis where the surface faces up).
vec3 anisotropy_direction(vec3 n, vec3 dp1, vec3 dp2, vec2 duv1, vec2 duv2, float rotation) {
    vec3 t = cross(dp2, n) * duv1.x + cross(n, dp1) * duv2.x;
    if (dot(n, cross(dp1, dp2)) < 0.0) t = -t;
    t -= dot(t, n) * n;
    if (dot(t, t) <= 1e-30) {
        vec3 up = abs(n.y) < 0.999 ? vec3(0.0, 1.0, 0.0) : vec3(1.0, 0.0, 0.0);
        t = up - dot(up, n) * n;
    }
    t = normalize(t);
    return cos(rotation) * t + sin(rotation) * cross(n, t);
}

float anisotropy_code(float anisotropy, vec3 t, vec3 n) {
    vec3 t0, b0;
    anisotropy_basis(n, t0, b0);
    float phi = atan(dot(t, b0), dot(t, t0));
    float q_phi = mod(floor(phi / ANISOTROPY_TWO_PI * ANISOTROPY_ANGLES + 0.5), ANISOTROPY_ANGLES);
    float q_a = clamp(floor(anisotropy * 255.0 + 0.5), 1.0, 255.0);
    return 2.0 + q_a + 256.0 * q_phi;
}

// Unpacks a code of anisotropy_code made against the normal n: false for an isotropic pixel.
bool anisotropy_unpack(float code, vec3 n, out float anisotropy, out vec3 t) {
    anisotropy = 0.0;
    t = vec3(0.0);
    if (code < 1.5) return false;
    float k = floor(code - 2.0 + 0.5);
    float q_phi = floor(k / 256.0);
    anisotropy = (k - 256.0 * q_phi) / 255.0;
    float phi = q_phi / ANISOTROPY_ANGLES * ANISOTROPY_TWO_PI;
    vec3 t0, b0;
    anisotropy_basis(n, t0, b0);
    t = cos(phi) * t0 + sin(phi) * b0;
    return true;
}
