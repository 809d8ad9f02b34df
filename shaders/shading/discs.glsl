// The closed-form terms of a light as a disc (lighting.frag): its diffuse term, its glossy term through
// a Phong lobe (summed over SUB_LIGHTS discs), its share above a plane, and whether a lobe is wider
// than it. Included by shading/lighting.frag after the lights.

// The diffuse term from the light itself instead of its PEM: the region as a uniform disc of angular
// radius a (its mean cosine (1 + cos a) / 2 is the region's, renderer/lighting/median_cut.py) carrying
// the region's energy E. Radiance = E / (pi * Omega(a)) * integral over the disc of max(0, n.w) dw;
// the integral is pi sin^2(a) mu when the disc is above the horizon (mu = n.l >= sin a), and otherwise
// the closed form of a horizon-clipped uniform cap (Snyder 1996, "Area light sources for real-time
// graphics"; the form used for sphere lights by Lagarde and de Rousiers 2014). Exact for a region
// above the horizon whatever its shape; no texture lookup.
vec3 diffuse_from_light(int i, vec3 n) {
    float mu = dot(n, lights[i].dir_scale.xyz);
    float sin_a = lights[i].params.w;
    float sin2 = sin_a * sin_a;
    float cos_a = sqrt(max(1.0 - sin2, 0.0));
    float integral;
    if (mu >= sin_a) {
        integral = PI * sin2 * mu;
    } else if (mu <= -sin_a) {
        integral = 0.0;
    } else if (sin_a < 0.01) {
        // A tiny disc straddling the horizon: the closed form cancels in float32 here; the share of
        // the disc above the plane times its mean cosine there, (mu + sin a)^2 / (4 sin a), is within
        // a fraction of a percent of the peak.
        integral = PI * sin2 * (mu + sin_a) * (mu + sin_a) / (4.0 * sin_a);
    } else {
        float sin_t = sqrt(max(1.0 - mu * mu, 1e-12));
        float cot_a = cos_a / sin_a;
        float y = clamp(-cot_a * mu / sin_t, -1.0, 1.0);
        float q = sin_t * sqrt(max(1.0 - y * y, 0.0));
        integral = max((mu * acos(y) - cot_a * q) * sin2 + atan(q, cot_a), 0.0);
    }
    float omega = 2.0 * PI * sin2 / (1.0 + cos_a);   // 2 pi (1 - cos a), without cancellation
    return lights[i].energy.rgb * (integral / (PI * max(omega, 1e-30)));
}

#ifdef SUB_LIGHTS
// FrameSettings.sub_lights: a region's glossy term in closed form summed over SUB_LIGHTS discs, its
// texels cut further by the same median cut (renderer/lighting/median_cut.py, SubLights); its
// visibility, diffuse term and PEMs stay the region's.
struct SubLight { vec4 dir_sin; vec4 energy; };   // unit direction, sine of the disc's radius; rgb
#ifdef SUB_LIGHTS_CAPACITY
// A uniform block where the driver's hold every light's discs (renderer.py; lighting.frag's lights).
layout(std140, binding = BUF_SUB_LIGHTS) uniform SubLightsBlock { SubLight sub_lights[SUB_LIGHTS_CAPACITY]; };
#else
layout(std430, binding = BUF_SUB_LIGHTS) readonly buffer SubLights { SubLight sub_lights[]; };
#endif
#endif

vec3 g_diffuse_exact = vec3(0.0);   // the closed-form diffuse term, added after the PEM terms' normalization
bool g_has_glossy = false;          // any lobe has weight (a Phong pixel: specular > 0)

// A small light's glossy term without its PEM: the region as a disc of angular radius a carrying its
// energy E, seen through a normalized Phong lobe of exponent s = 1 / inv_s around `axis` (paper Eq. 3;
// a Phong pixel's one lobe is about r with inv_s = 1 - g, a fitted material's lobes are where the fit
// put them, lobes.glsl). The disc's spread widens the lobe: in the small-angle (Gaussian) picture cos^s
// has variance 1 / s per axis and a uniform disc a^2 / 4, which add, so the lobe of exponent
// s' = 1 / (1 / s + a^2 / 4) carries E. Finite at g = 1 (the mirror): s' is then bounded by the disc's
// own size.
vec3 glossy_disc(vec3 l, float sin_a, vec3 energy, vec3 axis, float inv_s) {
    float s = 1.0 / max(max(inv_s, 0.0) + 0.25 * sin_a * sin_a, 1e-6);
    float c = clamp(dot(axis, l), 0.0, 1.0);   // float32 can reach 1 + 1e-7; s' up to ~4e6
    return energy * ((s + 1.0) / (2.0 * PI) * pow(c, s));
}

vec3 glossy_from_light(int i, vec3 axis, float inv_s) {
#ifdef SUB_LIGHTS
    vec3 sum = vec3(0.0);
    for (int j = 0; j < SUB_LIGHTS; ++j) {   // a constant count: the driver writes the loop out
        int k = i * SUB_LIGHTS + j;
        sum += glossy_disc(sub_lights[k].dir_sin.xyz, sub_lights[k].dir_sin.w, sub_lights[k].energy.rgb, axis, inv_s);
    }
    return sum;
#else
    return glossy_disc(lights[i].dir_scale.xyz, lights[i].params.w, lights[i].energy.rgb, axis, inv_s);
#endif
}

// Share of light i's energy, a disc of angular radius r (sin r = params.w) around its direction,
// above the plane of `normal` (linear in the cosine across the disc).
float disc_share_above(int i, vec3 normal) {
    float sin_r = lights[i].params.w;
    return clamp((dot(normal, lights[i].dir_scale.xyz) + sin_r) / (2.0 * sin_r), 0.0, 1.0);
}

// Where the plane of `normal` crosses light i's disc, in units of its radius along the direction in
// which the cosine grows (linear in the cosine, as disc_share_above): -1 at the disc's lowest edge
// (all of it above), 1 at its highest (all below). disc_share_above is (1 - x) / 2, clamped.
float horizon_crossing(int i, vec3 normal) {
    return -dot(normal, lights[i].dir_scale.xyz) / max(lights[i].params.w, 1e-6);
}

// A lobe's share of light i's disc above the plane of `normal`, which crosses it at x_h
// (horizon_crossing): the disc's energy (uniform in x, as disc_share_above has it) weighted by the
// lobe (axis, exponent 1 / inv_s, as the PEM lookup reads it) across the disc, the lobe taken as the
// Gaussian it is near its axis (pow(cos t, s) ~ exp(-s t^2 / 2): its axis at x_axis, its width
// 1 / sqrt(s) over the disc's radius) and the Gaussian's integral as a logistic (within 0.01). A lobe
// that is the same across the disc keeps disc_share_above; one that is itself zero below the plane
// (its axis at the normal) keeps nearly all of its PEM term, which holds no light from below the plane
// to remove; a narrow lobe keeps the share of its own footprint.
float lobe_share_above(int i, vec3 normal, float x_h, vec3 axis, float inv_s) {
    float linear = clamp(0.5 - 0.5 * x_h, 0.0, 1.0);
    if (x_h <= -1.0 || x_h >= 1.0) return linear;
    vec3 l = lights[i].dir_scale.xyz;
    float sin_r = max(lights[i].params.w, 1e-6);
    vec3 t = normal - dot(normal, l) * l;
    float len = length(t);
    if (len < 1e-6) return linear;
    float x_axis = dot(axis, t) / (len * sin_r);
    // 1.702 / sigma, sigma = sqrt(inv_s) / sin_r: the logistic's slope that matches the Gaussian's CDF.
    float k = 1.702 * sin_r / sqrt(clamp(inv_s, 1e-8, 1.0));
    float top = 1.0 / (1.0 + exp(-k * (1.0 - x_axis)));
    float den = top - 1.0 / (1.0 + exp(-k * (-1.0 - x_axis)));
    float num = top - 1.0 / (1.0 + exp(-k * (x_h - x_axis)));
    return den > 1e-4 ? clamp(num / den, 0.0, 1.0) : linear;
}

// GLOSSY_WIDE (glossy "wide"): a large light's glossy term in closed form too where the lobe is wider
// than its disc (variance 1 / s >= a^2 / 4, the two spreads of glossy_from_light): there the PEM's
// coarse MIP levels (a few texels a face) are the larger error; a narrower lobe reads the fine levels,
// which hold the region's own detail that a disc does not. Per pixel and lobe: inv_s = 1 / s may vary.
bool wide_lobe(int i, float inv_s) {
#ifdef GLOSSY_WIDE
    float sin_a = lights[i].params.w;
    return max(inv_s, 0.0) >= WIDE_LOBE_DISC_VARIANCE * sin_a * sin_a;
#else
    return false;
#endif
}
