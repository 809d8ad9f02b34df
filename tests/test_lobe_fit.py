"""Kautz and McCool's lobe fit (renderer/lighting/lobe_fit.py) on the exact BRDFs."""

from __future__ import annotations

import numpy as np
import pytest

from renderer.lighting.lobe_fit import PROFILES, fibonacci_sphere, fit_lobes, lobe_values
from renderer.shading import brdf


@pytest.mark.parametrize("kind", PROFILES)
@pytest.mark.parametrize("exponent", [3.0, 30.0, 300.0])
def test_one_lobe_reproduces_a_phong_lobe(exponent, kind):
    fit = fit_lobes(brdf.phong, np.radians(20.0), 1, kind, specular=1.0, exponent=exponent)
    assert np.allclose(fit.lobes[0].axis, [-np.sin(np.radians(20.0)), 0.0, np.cos(np.radians(20.0))])   # on r
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
    dirs, d_omega = fibonacci_sphere()
    v = np.array([np.sin(theta_v), 0.0, np.cos(theta_v)])
    # The slice's reflectivity, by an independent quadrature (the fit judges on a polar grid about r).
    reflectivity = float(fn(np.array([0.0, 0.0, 1.0]), v, dirs, **material).mean(axis=-1).sum() * d_omega)
    for fit in fits:
        assert fit.reflectivity == pytest.approx(reflectivity, rel=5e-3)
        # The energy correction: the fitted lobes' energy over the hemisphere is the slice's reflectivity.
        lobes = [(lobe.weight, lobe.exponent, np.array(lobe.axis)) for lobe in fit.lobes]
        assert float(lobe_values(lobes, dirs).sum() * d_omega) == pytest.approx(fit.reflectivity, rel=5e-3)
        assert 0.0 < fit.reflectivity <= 1.0
        # The joint refinement never leaves more error than the paper's greedy lobes.
        assert fit.rel_rms <= fit.greedy_rel_rms + 1e-12
    assert fits[1].rel_rms <= fits[0].rel_rms + 1e-12


def test_sheen_lobes_leave_the_mirror_direction():
    """Sheen reflects most at grazing angles: its best first lobe is not on the mirror direction, and
    it fits far better there than a lobe held on it."""
    kw = {"colour": (1.0, 1.0, 1.0), "roughness": 0.5}
    theta_v = np.radians(60.0)
    free = fit_lobes(brdf.sheen, theta_v, 1, **kw)
    v = np.array([np.sin(theta_v), 0.0, np.cos(theta_v)])
    r = 2.0 * v[2] * np.array([0.0, 0.0, 1.0]) - v
    held = fit_lobes(brdf.sheen, theta_v, 1, axis=r, **kw)
    assert not np.allclose(free.lobes[0].axis, r)
    assert free.rel_rms < 0.8 * held.rel_rms
