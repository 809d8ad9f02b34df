// Area-weighted unit vertex normals of the current positions, on the GPU: the rule of
// renderer/mesh.py vertex_normals (each vertex sums cross(p1 - p0, p2 - p0) of its faces; a sum that
// vanishes against the faces' areas gets the fallback normal). One invocation per vertex gathers the
// faces around it from a list made once per topology (scene.py), so no float atomics are needed.
layout(local_size_x = 64) in;

layout(std430, binding = BUF_NORMALS_POSITIONS) readonly buffer Positions { float pos[]; };     // (V, 3), the vertex buffer
layout(std430, binding = BUF_NORMALS_FACES) readonly buffer Faces { int faces[]; };         // (F, 3), the index buffer
layout(std430, binding = BUF_NORMALS_ADJACENCY_START) readonly buffer AdjacencyStart { int adj_start[]; };  // V + 1 offsets
layout(std430, binding = BUF_NORMALS_ADJACENCY) readonly buffer Adjacency { int adj_face[]; };  // faces per vertex, once per corner
layout(std430, binding = BUF_NORMALS_NORMALS) writeonly buffer Normals { float nrm[]; };      // (V, 3), the normal buffer

uniform int u_n_vertices;
uniform vec3 u_fallback;

vec3 position(int v) {
    return vec3(pos[3 * v], pos[3 * v + 1], pos[3 * v + 2]);
}

void main() {
    // Two-dimensional dispatch past 65535 groups (the least GL guarantees per dimension).
    int v = int(gl_GlobalInvocationID.x + gl_GlobalInvocationID.y * gl_NumWorkGroups.x * gl_WorkGroupSize.x);
    if (v >= u_n_vertices) return;
    vec3 sum = vec3(0.0);
    float area_sum = 0.0;
    for (int k = adj_start[v]; k < adj_start[v + 1]; ++k) {
        int f = 3 * adj_face[k];
        vec3 p0 = position(faces[f]);
        vec3 c = cross(position(faces[f + 1]) - p0, position(faces[f + 2]) - p0);
        sum += c;
        area_sum += length(c);
    }
    float len = length(sum);
    // As vertex_normals: a sum that nearly cancels is rounding noise with no meaningful direction.
    bool ok = !isnan(len) && !isinf(len) && len > 1e-6 * area_sum && len > 0.0;
    vec3 n = ok ? sum / len : u_fallback;
    nrm[3 * v] = n.x;
    nrm[3 * v + 1] = n.y;
    nrm[3 * v + 2] = n.z;
}
