// Anti-aliasing's edges pass, first half (renderer.py, _edges_pass): the pixels one surface covers
// whole take their shaded colour, the pixels no surface touches nothing, and the others, the edges,
// are marked (depth 0) for the second half (resolve.frag), whose early depth test then skips every
// block of pixels without one. A pixel lies wholly inside one plane when its samples are all covered
// and their depths and its centre's agree with one plane: the depth of a plane is affine in the pixel,
// so opposite samples of a pattern symmetric about the centre (GL's 4 sample pattern) sum to twice
// the centre's depth. A curved sheet's pixel can fail the test: it is then resolved as an edge, at a
// cost and to the same colour.

layout(binding = TEX_AA_MS_DEPTH) uniform sampler2DMS u_ms_depth;
layout(binding = TEX_AA_DEPTH) uniform sampler2D u_depth;           // the geometry pass's, at the centre
layout(binding = TEX_AA_COLOUR) uniform sampler2D u_colour;         // the lighting pass's output
// In window depth [0, 1]; below 0 where the driver's pattern has no opposite pairs (renderer.py):
// every pixel a surface touches is then an edge.
uniform float u_plane_depth_tolerance;

out vec4 o_color;

void main() {
    ivec2 px = ivec2(gl_FragCoord.xy);
    float centre = 2.0 * texelFetch(u_depth, px, 0).r;
    int covered = 0;
    float misfit = 0.0;
    // Samples s and AA_SAMPLES - 1 - s lie opposite each other about the centre (renderer.py checks).
    for (int s = 0; s < AA_SAMPLES / 2; ++s) {
        float a = texelFetch(u_ms_depth, px, s).r, b = texelFetch(u_ms_depth, px, AA_SAMPLES - 1 - s).r;
        covered += (a < 1.0 ? 1 : 0) + (b < 1.0 ? 1 : 0);
        misfit = max(misfit, abs(a + b - centre));
    }
    bool whole = covered == AA_SAMPLES && misfit <= u_plane_depth_tolerance;
    // The lighting pass's alpha is 1 on a surface, but a shadow catcher's share on its floor.
    o_color = whole ? texelFetch(u_colour, px, 0) : vec4(0.0);
    gl_FragDepth = whole || covered == 0 ? 1.0 : 0.0;
}
