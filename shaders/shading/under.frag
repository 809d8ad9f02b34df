// A layer seen through sheer cloth, blended under the image so far (renderer.py, _sheer_layers): the
// layer's colour is premultiplied by its alpha, and the blend adds it times what the image lets through
// (1 - its alpha).
layout(binding = TEX_UNDER_LAYER) uniform sampler2D u_layer;
in vec2 v_ndc;
out vec4 o_color;

void main() {
    o_color = texelFetch(u_layer, ivec2(gl_FragCoord.xy), 0);
}
