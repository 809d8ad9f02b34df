// Cube-map geometry, mirroring renderer/envmap/cube.py (OpenGL's face order and (u, v) axes:
// GL 4.5 spec table 8.19). face 0..5 = +X -X +Y -Y +Z -Z; u along columns (s), v along rows (t).

vec3 face_uv_to_dir(int face, float u, float v) {
    if (face == 0) return vec3(1.0, -v, -u);
    if (face == 1) return vec3(-1.0, -v, u);
    if (face == 2) return vec3(u, 1.0, v);
    if (face == 3) return vec3(u, -1.0, -v);
    if (face == 4) return vec3(u, -v, 1.0);
    return vec3(-u, -v, -1.0);
}

// Face and (u, v) in [-1, 1] of a direction; ties go to X, then Y, then Z as in cube.py.
int dir_to_face_uv(vec3 d, out vec2 uv) {
    vec3 a = abs(d);
    if (a.x >= a.y && a.x >= a.z) {
        float ma = max(a.x, 1e-30);
        if (d.x >= 0.0) { uv = vec2(-d.z, -d.y) / ma; return 0; }
        uv = vec2(d.z, -d.y) / ma; return 1;
    }
    if (a.y >= a.z) {
        float ma = max(a.y, 1e-30);
        if (d.y >= 0.0) { uv = vec2(d.x, d.z) / ma; return 2; }
        uv = vec2(d.x, -d.z) / ma; return 3;
    }
    float ma = max(a.z, 1e-30);
    if (d.z >= 0.0) { uv = vec2(d.x, -d.y) / ma; return 4; }
    uv = vec2(-d.x, -d.y) / ma; return 5;
}

// Texel (face, row, col) of a face of size n, where row/col may lie beyond the face: resolved through
// the direction of the extended texel centre, so the k-th texel past an edge is the k-th texel into
// the neighbouring face (no seams). Returns ivec3(face, row, col).
ivec3 resolve_texel(int face, int row, int col, int n) {
    if (row >= 0 && row < n && col >= 0 && col < n) return ivec3(face, row, col);
    float inv = 2.0 / float(n);
    vec3 d = face_uv_to_dir(face, (float(col) + 0.5) * inv - 1.0, (float(row) + 0.5) * inv - 1.0);
    vec2 uv;
    int f = dir_to_face_uv(d, uv);
    ivec2 cr = clamp(ivec2(floor((uv + 1.0) * 0.5 * float(n))), ivec2(0), ivec2(n - 1));
    return ivec3(f, cr.y, cr.x);
}
