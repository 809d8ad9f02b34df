// The build's live workgroups (pem.py, _live_tiles): 0 for a workgroup whose texels read only texels
// outside its region's reach, all zeros; it writes zeros without the arithmetic (the same result).
layout(std430, binding = BUF_PEM_TILES) readonly buffer Tiles { int live_tiles[]; };

uniform int u_tiles_first;   // this dispatch's first workgroup in live_tiles; -1: every one live

bool tile_is_live() {
    if (u_tiles_first < 0) return true;
    uvec3 g = gl_WorkGroupID, count = gl_NumWorkGroups;
    return live_tiles[u_tiles_first + int((g.z * count.y + g.y) * count.x + g.x)] != 0;
}
