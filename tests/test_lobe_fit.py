"""Kautz and McCool's lobe fit (renderer/lighting/lobe_fit.py) on the exact BRDFs."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.lighting.lobe_fit import PROFILES, fit_lobes
from renderer.shading import brdf


@pytest.mark.parametrize("kind", PROFILES)
@pytest.mark.parametrize("exponent", [3.0, 30.0, 300.0])
def test_one_lobe_reproduces_a_phong_lobe(exponent, kind):
    fit = fit_lobes(brdf.phong, np.radians(20.0), 1, kind, specular=1.0, exponent=exponent)
    (lobe,) = fit.lobes
    assert lobe.exponent == pytest.approx(exponent, rel=2e-2)
    assert lobe.weight == pytest.approx(1.0, rel=2e-2)
    assert fit.rel_rms < 0.03


@pytest.mark.parametrize("name, fn, material", [
    ("ggx", brdf.ggx, {"base": (1.0, 1.0, 1.0), "metallic": 1.0, "roughness": 0.3}),
    ("sheen", brdf.sheen, {"colour": (1.0, 1.0, 1.0), "roughness": 0.5}),
])
def test_the_lobes_reflect_what_the_slice_reflects_and_more_lobes_fit_better(name, fn, material):
    theta_v = np.radians(45.0)
    fits = [fit_lobes(fn, theta_v, k, **material) for k in (1, 2)]
    for fit in fits:
        # The energy correction: the fitted lobes' energy over the hemisphere is the slice's reflectivity.
        from renderer.lighting.lobe_fit import N, PolarGrid, phong_profile

        grid = PolarGrid.about(np.array(fit.lobes[0].axis))
        upper = (grid.dirs @ N) > 0
        energy = sum(lobe.weight * float(np.sum((phong_profile(grid.theta, lobe.exponent)[:, None] * upper)
                                                * grid.d_omega)) for lobe in fit.lobes)
        assert energy == pytest.approx(fit.reflectivity, rel=1e-9)
        assert 0.0 < fit.reflectivity <= 1.0
    assert fits[1].rel_rms <= fits[0].rel_rms + 1e-12
