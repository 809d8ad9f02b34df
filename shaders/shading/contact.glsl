// Contact shadows (lighting.frag, CONTACT_SHADOWS): the occluders nearer a surface than a shadow map
// resolves, found in the geometry pass's positions. Included by shading/lighting.frag.

// Contact shadows (full mode): occluders nearer than a shadow map resolves. A light's map sees
// nothing closer than its normal offset and its variance floor, a few of its texels (millimetres on
// a garment): a collar over the neck, a fold's lips. The geometry pass's positions do: per pixel, the
// neighbours within u_contact_radius (world units) along CONTACT_SLICES screen lines through the
// pixel, each line with the eye a plane that holds the view direction (a slice). Each neighbour that
// rises above the pixel's own plane is solid from its front (what the camera sees) to
// u_contact_thickness behind it, and hides that range of angles from the view direction in its
// slice: a mask of 32 sectors per half-slice (visibility bitmasks, after Therrien et al. 2023, here
// uniform in the cosine so that no angle needs an acos). A light lies in the half-slice of its own
// screen direction; the occluded share of its disc (its angular radius either side of its own
// sector, half a sector at least) is read from the masks of the two neighbouring half-slices and
// interpolated. VIS_i takes the smaller of this and the shadow map's. Only what the camera sees can
// occlude (what hides behind the visible surface is the map's), within the radius only; a finite
// thickness keeps a garment's near layer at a silhouette from shadowing the far layer from a light
// behind both, which a horizon (a height field: everything behind the front is solid) did.
uniform mat4 u_view_proj;        // the camera's
uniform vec2 u_image_size;       // pixels
uniform float u_focal_px;        // pixels per unit of view-space slope: height / (2 tan(fov_y / 2))
uniform float u_contact_radius;  // world units
uniform float u_contact_thickness;  // world units (renderer.py, CONTACT_THICKNESS)
// Sine of the least elevation above the triangle's plane at which a neighbour occludes: a mesh's
// facets bend by a few degrees between neighbouring pixels on a smooth surface.
const float CONTACT_MIN_ELEVATION = 0.1;
const int CONTACT_DIRS = 2 * CONTACT_SLICES;   // screen direction k at angle k pi / CONTACT_SLICES
// Per direction: the occluded sectors of its half-plane, 32 bits uniform in (1 - cos) / 2 of the
// angle from the view direction (bit 0 along it, bit 31 opposite).
uint g_sectors[CONTACT_DIRS];
// Per light: xyz = x, y, w of the camera's view_proj times (direction, 0); w: its angular radius,
// at least 0.01 radians.
layout(std140, binding = BUF_LIGHT_SCREEN) uniform LightScreen { vec4 light_screen[MAX_LIGHTS]; };   // a uniform block, as the lights'
vec4 g_clip;                     // the pixel's clip-space position

// Bits [a, b) of a 32-bit mask (a, b in 0..32).
uint bit_range(int a, int b) {
    if (b <= a) return 0u;
    uint hi = b >= 32 ? 0xffffffffu : (1u << uint(b)) - 1u;
    return hi & ~((1u << uint(a)) - 1u);
}

void contact_sectors(vec3 p, vec3 v, vec3 plane, ivec2 px) {
    g_clip = u_view_proj * vec4(p, 1.0);
    ivec2 size = ivec2(u_image_size);
    float radius_px = u_contact_radius * u_focal_px / max(g_clip.w, 1e-30);
    // A step per two pixels of the radius, at most CONTACT_STEPS.
    int steps = clamp(int(ceil(0.5 * radius_px)), 1, CONTACT_STEPS);
    for (int k = 0; k < CONTACT_DIRS; ++k) {
        float phi = float(k) * (PI / float(CONTACT_SLICES));
        vec2 d = vec2(cos(phi), sin(phi));
        d /= max(abs(d.x), abs(d.y));   // whole pixels along the major axis
        uint mask = 0u;
        for (int j = 1; j <= steps; ++j) {
            // Denser near the pixel (the nearest occluders are the ones the maps miss), a pixel apart at
            // least: at t^4 of the radius, the first half of the steps a pixel apart. Chosen among t, t^1.5,
            // t^2, t^3 and t^4 at the same steps on the broad benchmark's tuning maps, where t^4 had every
            // preset's lowest error; docs/broad/broad-256.md holds the held-out result.
            float t = float(j) / float(steps);
            float t2 = t * t;
            ivec2 q = px + ivec2(round(d * max(radius_px * t2 * t2, float(j))));
            if (any(lessThan(q, ivec2(0))) || any(greaterThanEqual(q, size))) break;
            vec4 s = texelFetch(u_g_position, q, 0);
            if (s.w < 0.0) continue;   // no surface there (the geometry pass clears w to -1)
            vec3 e = s.xyz - p;
            float len = length(e);
            // Only what rises above the surface's own plane: the plane itself is the terminator's and
            // the PEMs' (a flat or convex neighbourhood hides nothing more).
            if (!(dot(e, plane) > CONTACT_MIN_ELEVATION * len)) continue;
            // Solid from its front (what the camera sees) to u_contact_thickness behind it (along the
            // pixel's view direction, near enough to the sample's own within the radius); over the
            // radius' outer half the range shrinks to its front, so that an occluder crossing the
            // radius does not flicker.
            float w = 1.0 - smoothstep(0.5 * u_contact_radius, u_contact_radius, len);
            vec3 b = e - u_contact_thickness * v;
            float front = 16.0 * (1.0 - dot(e, v) / len);
            float back = 16.0 * (1.0 - dot(b, v) / max(length(b), 1e-30));
            mask |= bit_range(int(round(front)), int(round(mix(front, back, w))));
        }
        g_sectors[k] = mask;
    }
}

// The occluded sectors of a mask up to x (in sectors, 0..32), the last partly. Without branches or a
// shift by 32: x = 32 reads as bit 31 in full (bit_range(0, i) gives the same bits through a branch,
// slower on every scene measured).
float sectors_below(uint mask, float x) {
    float xc = clamp(x, 0.0, 32.0);
    int i = min(int(xc), 31);
    return float(bitCount(mask & ((1u << uint(i)) - 1u))) + (xc - float(i)) * float((mask >> uint(i)) & 1u);
}

// g_sectors[k] by selects: a per-pixel index into a private array is a gather per lane on a CPU rasterizer.
uint sectors_of(int k) {
    uint m = g_sectors[0];
    for (int j = 1; j < CONTACT_DIRS; ++j) m = k == j ? g_sectors[j] : m;
    return m;
}

float contact_visibility(int i, vec3 v) {
    vec4 ls = light_screen[i];
    // The screen direction of the light at the pixel: d(ndc)/dt of p + t l, in pixels (a positive
    // factor dropped).
    vec2 d = (ls.xy * g_clip.w - g_clip.xy * ls.z) * u_image_size;
    // Its angle as a "diamond angle" in [0, 4): 0, 1, 2, 3 at 0, 90, 180, 270 degrees, 0.5 at 45,
    // monotonic between (exact at the slices' directions: they are the weights' nodes), no atan.
    float s = abs(d.x) + abs(d.y);
    vec2 u = s > 0.0 ? d / s : vec2(1.0, 0.0);
    float dia = u.y >= 0.0 ? (u.x >= 0.0 ? u.y : 1.0 - u.x) : (u.x < 0.0 ? 2.0 - u.y : 3.0 + u.x);
    float x = dia * (float(CONTACT_SLICES) / 2.0);
    int k0 = min(int(x), CONTACT_DIRS - 1);
    int k1 = (k0 + 1) % CONTACT_DIRS;
    float c = dot(lights[i].dir_scale.xyz, v);
    // The light's disc as an interval of sectors around its own (half a sector at least), moved
    // inside [0, 32] where it would reach past the view direction or its opposite (there the cosine
    // folds back: no part of the disc lies beyond), the occluded share of it per slice, then between
    // the two slices.
    float centre = 16.0 * (1.0 - c);
    float half_width = clamp(16.0 * sqrt(max(1.0 - c * c, 0.0)) * ls.w, 0.5, 16.0);
    float lo = clamp(centre - half_width, 0.0, 32.0 - 2.0 * half_width), hi = lo + 2.0 * half_width;
    uint m0 = sectors_of(k0), m1 = sectors_of(k1);
    float occ0 = sectors_below(m0, hi) - sectors_below(m0, lo);
    float occ1 = sectors_below(m1, hi) - sectors_below(m1, lo);
    return 1.0 - clamp(mix(occ0, occ1, x - float(k0)) / (2.0 * half_width), 0.0, 1.0);
}
