// The research modes: the paper's Fig. 6 ambient-occlusion baselines and the plain many-light
// baseline of its introduction. lighting.frag includes this file in every variant, and its contents
// are compiled only under MODE_AO_GREY, MODE_AO_COLOUR and MODE_MANY_LIGHTS: the production variants
// (MODE_FULL, MODE_NO_OCCLUSION) hold none of it.

#if MODE == MODE_AO_GREY || MODE == MODE_AO_COLOUR
vec3 g_ao_rgb = vec3(0.0), g_ao_norm = vec3(0.0);

// Light i in the ambient-occlusion baselines: unshadowed lighting, and an occlusion factor that
// averages VIS_i with cosine weights, by solid angle (grey) or by energy (colour).
void add_light_ao(int i, vec3 pem_d, vec3 pem_g[N_LOBES], vec3 n, vec3 ws_pos, bool sharp, float scale) {
    float vis = visibility(i, ws_pos, n, sharp);
    float cosine = max(dot(n, lights[i].dir_scale.xyz), 0.0);
    vec3 w = MODE == MODE_AO_GREY ? vec3(lights[i].params.z) : lights[i].energy.rgb;
    g_ao_rgb += vis * cosine * w;
    g_ao_norm += cosine * w;
    g_diffuse += pem_d;
    for (int k = 0; k < N_LOBES; ++k) g_glossy[k] += scale * pem_g[k];
}

// The occlusion factor applied to both terms.
vec3 ambient_occlusion() {
    return g_ao_rgb / max(g_ao_norm, vec3(1e-30));
}
#endif

#if MODE == MODE_MANY_LIGHTS
// The N lights used for shading as well as for shadows, each a directional light carrying its
// region's energy (no PEMs).
void shade_many_lights(vec3 n, vec3 ws_position) {
    for (int i = 0; i < u_n_lights; ++i) {
        vec3 l = lights[i].dir_scale.xyz;
        vec3 e = (lights[i].shadow.y > 0.5 ? visibility(i, ws_position, n, true)
                                           : visibility(i, ws_position, n, false)) * lights[i].energy.rgb;
        g_diffuse += e * max(dot(n, l), 0.0) / PI;
        for (int k = 0; k < N_LOBES; ++k) {
            float s_phong = 1.0 / max(g_lobe_inv_s[k], 1e-4);   // Eq. 3, capped so g = 1 stays finite
            g_glossy[k] += e * (s_phong + 1.0) / (2.0 * PI) * pow(max(dot(g_lobe_axis[k], l), 0.0), s_phong);
        }
    }
}
#endif
