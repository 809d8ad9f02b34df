"""The area lights' figure (`garment-render area-lights`): a map with its found lights drawn over it,
beside its ambient remainder. The lab's (matplotlib), apart from the decomposition it draws
(renderer/lighting/area_lights.py)."""

from __future__ import annotations

import numpy as np

from renderer.lighting.area_lights import Decomposition, disc_tangents
from renderer.lighting.median_cut import LUMINANCE_RGB


def write_preview(cube: np.ndarray, dec: Decomposition, path, title: str = "") -> None:
    """The map with the found lights' discs drawn over it, beside the ambient remainder (the seed's
    Figure 2), both lat-long, exposed alike."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from renderer.envmap.layouts import Layout, cube_to_latlong, dir_to_image

    h, w = 256, 512
    images = [cube_to_latlong(np.asarray(cube, np.float32)[..., :3], h, w), cube_to_latlong(dec.ambient, h, w)]
    scale = float(np.quantile(images[0] @ LUMINANCE_RGB, 0.9)) or 1.0
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.4))
    for ax, img, name in zip(axes, images, ("map and its area lights", f"ambient remainder ({dec.ambient_share:.0%})")):
        ax.imshow(np.clip(img / scale / 2.0, 0.0, 1.0) ** (1 / 2.2), extent=(0, w, h, 0))
        ax.set_title(name, fontsize=9)
        ax.set_axis_off()
    for k, light in enumerate(dec.lights):
        c = np.asarray(light.direction)
        t, b = disc_tangents(c)
        a = np.linspace(0.0, 2.0 * np.pi, 181)[:, None]
        ring = np.cos(light.radius_rad) * c + np.sin(light.radius_rad) * (np.cos(a) * t + np.sin(a) * b)
        u, v, _ = dir_to_image(ring, Layout.LATLONG, h, w)
        cut = np.flatnonzero(np.abs(np.diff(u)) > w / 2) + 1     # the seam: draw each side apart
        for part_u, part_v in zip(np.split(u, cut), np.split(v, cut)):
            axes[0].plot(part_u, part_v, color="cyan", lw=1.0)
        cu, cv, _ = dir_to_image(c, Layout.LATLONG, h, w)
        axes[0].text(cu, cv, f"{k + 1}: {light.share:.0%}", color="cyan", fontsize=7, ha="center", va="center")
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
