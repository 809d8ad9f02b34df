// The layers behind sheer cloth (renderer.py, _sheer_layers): where the image is already opaque, the
// layer's depth goes back to the far plane, so that the lighting pass (drawn where the depth is nearer)
// shades nothing there (a kept body's surface copied in under the cloth, say).
layout(binding = TEX_PEEL_OPACITY) uniform sampler2D u_peel_opacity;
in vec2 v_ndc;
out vec4 o_color;

void main() {
    if (texelFetch(u_peel_opacity, ivec2(gl_FragCoord.xy), 0).a < 0.999) discard;
    o_color = vec4(0.0);
    gl_FragDepth = 1.0;
}
