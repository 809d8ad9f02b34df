// Anti-aliasing's edges pass, second half (the first, classify.frag, wrote the other pixels and marked
// these in the depth buffer): each edge pixel as the mean of its AA_SAMPLES samples, alpha the share of
// them a surface covers, times the lighting pass's alpha there (1, but a shadow catcher's floor's share)
// (renderer.py, _edges_pass). The geometry and lighting passes ran once a pixel,
// at its centre, as without anti-aliasing; the coverage pass left the surfaces' depth at every sample.
// A sample's surface point is its depth unprojected at its own position in the pixel. It takes the
// colour of its own pixel where that pixel's centre shaded the same surface, else the mean colour of
// the neighbours (3 x 3) whose centres did, else (a sliver no centre saw) the neighbour's whose surface
// lies nearest; a sample with no surface adds nothing. The colour is so premultiplied by coverage, over
// black: the renderer blends the background in under it. This is subpixel reconstruction (Chajed and
// McGuire, "Subpixel Reconstruction Antialiasing for Deferred Shading", I3D 2011) with surfaces told
// apart by their planes instead of bilateral weights: shading stays one a pixel.
//
// Two surfaces are one where the sample lies within u_plane_tolerance_px pixel footprints of the
// shaded point's plane (its triangle's, gbuffer.frag's geometric normal): a sheet's neighbouring
// triangles are, a sleeve over a torso or a garment's edge over the body behind are not.

layout(binding = TEX_AA_MS_DEPTH) uniform sampler2DMS u_ms_depth;
layout(binding = TEX_AA_POSITION) uniform sampler2D u_position;     // xyz: world position; w < 0: no surface
layout(binding = TEX_AA_GEOMETRIC) uniform sampler2D u_geometric;   // xyz: the triangle's plane normal
layout(binding = TEX_AA_COLOUR) uniform sampler2D u_colour;         // the lighting pass's output

uniform mat4 u_inv_view_proj;                   // of the geometry pass's projection (its depth range)
uniform vec2 u_sample_positions[AA_SAMPLES];    // in the pixel, from its lower left corner (the driver's)
uniform vec3 u_camera_pos;
uniform float u_footprint_per_distance;         // a pixel's side at unit distance (2 tan(fov_y / 2) / H)
uniform float u_plane_tolerance_px;

out vec4 o_color;

// The full-screen triangle lies at the far plane and the depth test is GREATER against classify.frag's
// marks: only edge pixels pass, and blocks with none are skipped before shading.
layout(early_fragment_tests) in;

void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    ivec2 size = textureSize(u_colour, 0);
    // The 3 x 3 neighbourhood's shaded surfaces (a plane: point, normal) and colours, [4] the pixel's
    // own; outside the image or with no surface, none (`shaded` false). Straight-line code, no branch on
    // a pixel's own values: a CPU rasterizer runs a block of pixels in lock step.
    // colour: the lighting pass's rgba (its alpha 1 on a surface, a shadow catcher's share on its floor).
    vec3 point[9], normal[9];
    vec4 colour[9];
    bool shaded[9];
    for (int k = 0; k < 9; ++k) {
        ivec2 q = px + ivec2(k % 3 - 1, k / 3 - 1);
        bool inside = all(greaterThanEqual(q, ivec2(0))) && all(lessThan(q, size));
        q = clamp(q, ivec2(0), size - 1);
        vec4 p = texelFetch(u_position, q, 0);
        shaded[k] = inside && p.w >= 0.0;
        point[k] = p.xyz;
        normal[k] = texelFetch(u_geometric, q, 0).xyz;
        colour[k] = texelFetch(u_colour, q, 0);
    }
    vec4 sum = vec4(0.0);
    for (int s = 0; s < AA_SAMPLES; ++s) {
        float depth = texelFetch(u_ms_depth, px, s).r;
        vec2 ndc = (vec2(px) + u_sample_positions[s]) / vec2(size) * 2.0 - 1.0;
        vec4 h = u_inv_view_proj * vec4(ndc, depth * 2.0 - 1.0, 1.0);
        vec3 x = h.xyz / h.w;
        float inv_tol = 1.0 / max(u_plane_tolerance_px * u_footprint_per_distance * distance(u_camera_pos, x), 1e-30);
        vec4 found = vec4(0.0);
        float n = 0.0, nearest = 3e38;
        vec4 nearest_colour = colour[4];
        for (int k = 0; k < 9; ++k) {
            float d = shaded[k] ? abs(dot(x - point[k], normal[k])) * inv_tol : 3e38;
            float same = d <= 1.0 ? 1.0 : 0.0;
            found += same * colour[k];
            n += same;
            nearest_colour = d < nearest ? colour[k] : nearest_colour;
            nearest = min(d, nearest);
        }
        float own = shaded[4] ? abs(dot(x - point[4], normal[4])) * inv_tol : 3e38;
        vec4 c = own <= 1.0 ? colour[4] : n > 0.0 ? found / n : nearest_colour;
        bool hit = depth < 1.0;   // cleared: no surface at this sample
        sum += hit ? c : vec4(0.0);
    }
    o_color = sum / float(AA_SAMPLES);
}
