// The environment map itself seen along each view ray, behind the scene (renderer/shading/background.py):
// a lat-long source read directly (BACKGROUND_LATLONG), else a cube, each with its MIP chain. The
// lat-long is read over the pixel's footprint (footprint_mean); the cube by four rays spread over the
// pixel, each filtered over its quarter of the footprint (a cube's own derivatives, closer to the
// pixel's box than one lookup).
#ifdef BACKGROUND_LATLONG
layout(binding = TEX_ENVIRONMENT) uniform sampler2D u_env;
#else
layout(binding = TEX_ENVIRONMENT) uniform samplerCube u_env;
#endif

uniform mat4 u_inv_view_proj;
uniform mat3 u_env_from_world;   // a turned environment is read through the inverse turn (PEMSet.turned)
in vec2 v_ndc;
out vec4 o_color;

// The view ray through a point of the screen, in the map's own frame.
vec3 view_ray(vec2 ndc) {
    vec4 a = u_inv_view_proj * vec4(ndc, -1.0, 1.0);
    vec4 b = u_inv_view_proj * vec4(ndc, 1.0, 1.0);
    return u_env_from_world * normalize(b.xyz / b.w - a.xyz / a.w);
}

#ifdef BACKGROUND_LATLONG
const float PI = 3.14159265358979;

// Normalized lat-long coordinates (x right from -Z through +X, y down from the zenith +Y) of a unit
// direction: renderer/envmap/layouts.py's convention; row 0 of the image is t = 0 of the texture.
vec2 latlong_uv(vec3 d) {
    return vec2(atan(d.x, -d.z) / (2.0 * PI) + 0.5, 0.5 - atan(d.y, length(d.xz)) / PI);
}

// The change of latlong_uv along a small change dd of the unit direction d, analytic: continuous where
// u wraps from 1 to 0 (towards +Z), which the screen-space derivatives are not.
// Near the poles a pixel spans many texels of a row, up to the whole row.
vec2 latlong_duv(vec3 d, vec3 dd) {
    float r2 = max(dot(d.xz, d.xz), 1e-12);
    float r = sqrt(r2);
    float dphi = (d.x * dd.z - d.z * dd.x) / r2;
    float dtheta = r * dd.y - d.y * dot(d.xz, dd.xz) / r;
    return vec2(clamp(dphi / (2.0 * PI), -1.0, 1.0), -dtheta / PI);
}

// Lookups at most along a footprint's width (GL's own anisotropic filtering is not in GL 4.5 core).
const int STRETCH_TAPS = 8;

// The mean of the texture over the footprint whose sides change uv by gx and gy, about uv. A lat-long
// stretches only its rows (by 1 / cos(latitude)), so the footprint is taken as the box of its extents
// along u and along v: where it is much wider than tall (towards the poles a pixel spans many of a
// row's texels, few rows) it is read as several lookups across its width, each filtered over its
// share; where even STRETCH_TAPS shares would reach rows far from the pixel (a coarse level, within a
// degree of a pole) each is no wider than twice the height: the lookups sample the row instead.
vec3 footprint_mean(vec2 uv, vec2 gx, vec2 gy) {
    vec2 texels = vec2(textureSize(u_env, 0));
    vec2 extent = max(abs(gx), abs(gy));   // uv
    float wide = extent.x * texels.x, tall = max(extent.y * texels.y, 1e-6);   // texels
    int n = int(clamp(ceil(wide / tall), 1.0, float(STRETCH_TAPS)));
    float share = extent.x / float(n) * min(1.0, 2.0 * tall * float(n) / max(wide, 1e-6));
    vec3 c = vec3(0.0);
    for (int i = 0; i < n; ++i) {
        vec2 p = uv + vec2(extent.x * ((float(i) + 0.5) / float(n) - 0.5), 0.0);
        c += textureGrad(u_env, p, vec2(share, 0.0), vec2(0.0, extent.y)).rgb;
    }
    return c / float(n);
}
#endif

void main() {
    vec2 px = vec2(dFdx(v_ndc.x), dFdy(v_ndc.y));   // one pixel in NDC
#ifdef BACKGROUND_LATLONG
    // One lookup filtered over the pixel's whole footprint.
    vec3 d = view_ray(v_ndc);
    vec3 step_x = view_ray(v_ndc + vec2(px.x, 0.0)) - d;
    vec3 step_y = view_ray(v_ndc + vec2(0.0, px.y)) - d;
    o_color = vec4(footprint_mean(latlong_uv(d), latlong_duv(d, step_x), latlong_duv(d, step_y)), 0.0);
#else
    vec3 c = vec3(0.0);
    for (int k = 0; k < 4; ++k) {
        vec2 offset = (vec2(float(k & 1), float(k >> 1)) - 0.5) * 0.5 * px;
        c += texture(u_env, view_ray(v_ndc + offset), -1.0).rgb;
    }
    o_color = vec4(0.25 * c, 0.0);
#endif
}
