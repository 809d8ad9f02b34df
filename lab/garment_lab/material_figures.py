"""The lobe fit's report: an analogue of Kautz and McCool's Figure 7 (relative RMS error of the fit
against view elevation, per BRDF and lobe count) and the fitted lobes against the exact slices in the
plane of incidence, from the stored tables (material_lobes.py) and fresh fits of the slices drawn.

`garment-render brdf-lobes` writes brdf_lobes_fig7.png, brdf_lobes_slices.png, brdf_lobes.md and
brdf_lobes.json. Everything is computed by lobe_fit.py and material_lobes.py; this module only
evaluates and draws it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from renderer.lighting import material_lobes
from renderer.lighting.lobe_fit import N, lobe_values, view_direction
from renderer.shading import brdf

# The target for the fit itself: rel. RMS <= 5 % at every view elevation, with two lobes, for
# GGX roughness >= 0.2 and for sheen.
TARGET_REL_RMS = 0.05
TARGET_GGX_MIN_ROUGHNESS = 0.2
ROUGHNESS_ROWS = (0.2, 0.5, 0.8)
SLICE_VIEWS_DEG = (0.0, 45.0, 75.0)


def _row(tables, roughness: float) -> int:
    return int(np.argmin(np.abs(tables.roughness - roughness)))


def summary(tables=None) -> dict:
    """Per model and lobe count: the fit's rel. RMS per roughness node and view (after / before the
    joint refinement) and the target's verdict."""
    tables = tables or material_lobes.load()
    out = {"roughness": tables.roughness.tolist(), "theta_v_deg": np.degrees(tables.theta_v).round(3).tolist(),
           "target_rel_rms": TARGET_REL_RMS, "models": {}}
    for model in material_lobes.MODELS:
        rows = tables.roughness >= (TARGET_GGX_MIN_ROUGHNESS - 1e-9 if model == "ggx" else 0.0)
        entry = {}
        for count in range(1, material_lobes.MAX_LOBES + 1):
            rms = tables.rms(model, count)
            worst = float(rms[rows].max())
            entry[str(count)] = {"rel_rms": rms.round(4).tolist(),
                                 "greedy_rel_rms": tables.rms(model, count, greedy=True).round(4).tolist(),
                                 "median": float(np.median(rms[rows])), "worst_in_target_range": worst,
                                 "target_met": worst <= TARGET_REL_RMS}
        out["models"][model] = entry
    return out


def markdown(s: dict) -> str:
    lines = ["# The lobe fit of the physically based BRDFs (Kautz and McCool's Figure 7)", "",
             "Made by `garment-render brdf-lobes` from the stored tables (renderer/data/material_lobes.npz).",
             "Relative RMS error of the fitted lobes against the exact slice over the hemisphere, after the",
             "energy correction; the paper's greedy fit alone in brackets. GGX is fitted colourless (F0 = 1).", ""]
    th = s["theta_v_deg"]
    cols = [0, len(th) // 3, 2 * len(th) // 3, len(th) - 1]
    for model, entry in s["models"].items():
        lines += [f"## {model}", "", "| roughness | lobes | " + " | ".join(f"{th[c]:.0f} deg" for c in cols) + " |",
                  "|---|---|" + "---|" * len(cols)]
        for r in ROUGHNESS_ROWS:
            i = int(np.argmin(np.abs(np.array(s["roughness"]) - r)))
            for count, e in entry.items():
                cells = [f"{e['rel_rms'][i][c]:.3f} ({e['greedy_rel_rms'][i][c]:.3f})" for c in cols]
                lines.append(f"| {s['roughness'][i]:.2f} | {count} | " + " | ".join(cells) + " |")
        lines.append("")
        scope = f"roughness >= {TARGET_GGX_MIN_ROUGHNESS}" if model == "ggx" else "every roughness"
        for count, e in entry.items():
            verdict = "met" if e["target_met"] else \
                f"missed by {e['worst_in_target_range'] / s['target_rel_rms']:.1f}x"
            lines.append(f"- {count} lobe(s), {scope}: median {e['median']:.3f}, worst "
                         f"{e['worst_in_target_range']:.3f}; target <= {s['target_rel_rms']:.2f}: {verdict}")
        lines.append("")
    return "\n".join(lines)


def write_brdf_lobe_report(out: Path) -> dict:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tables = material_lobes.load()
    s = summary(tables)
    th = np.degrees(tables.theta_v)

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, model in zip(axes, material_lobes.MODELS):
        for r, colour in zip(ROUGHNESS_ROWS, ("tab:blue", "tab:orange", "tab:green")):
            i = _row(tables, r)
            for count, style in ((1, ":"), (2, "-")):
                ax.plot(th, tables.rms(model, count)[i], style, color=colour,
                        label=f"roughness {tables.roughness[i]:.2f}, {count} lobe{'s' if count > 1 else ''}")
        ax.axhline(TARGET_REL_RMS, color="grey", lw=0.8)
        ax.set_title(model)
        ax.set_xlabel("view elevation theta_v (deg)")
        ax.set_yscale("log")
    axes[0].set_ylabel("relative RMS error of the fit")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "brdf_lobes_fig7.png", dpi=120)
    plt.close(fig)

    # The slices in the plane of incidence: exact against the two fitted lobes, at roughness 0.5.
    fig, axes = plt.subplots(2, len(SLICE_VIEWS_DEG), figsize=(12, 6.5), subplot_kw={"projection": "polar"})
    angles = np.linspace(-np.pi / 2, np.pi / 2, 721)   # from the normal, positive towards the view
    dirs = np.stack([np.sin(angles), np.zeros_like(angles), np.cos(angles)], -1)
    for row, model in enumerate(material_lobes.MODELS):
        for col, view in enumerate(SLICE_VIEWS_DEG):
            theta_v = np.radians(view)
            v = view_direction(theta_v)
            fit = material_lobes.fit_cell(model, 0.5, theta_v, 2)
            fn = brdf.ggx if model == "ggx" else brdf.sheen
            kw = dict(base=1.0, metallic=1.0, roughness=0.5) if model == "ggx" else dict(colour=1.0, roughness=0.5)
            exact = fn(N, v, dirs, **kw).mean(-1)
            lobes = [(lobe.weight, lobe.exponent, np.array(lobe.axis)) for lobe in fit.lobes]
            fitted = lobe_values(lobes, dirs)
            ax = axes[row, col]
            ax.plot(angles, exact, color="tab:blue", label="exact slice")
            ax.plot(angles, fitted, color="tab:red", label="2 fitted lobes")
            ax.set_thetamin(-90)
            ax.set_thetamax(90)
            ax.set_theta_zero_location("N")
            ax.set_title(f"{model} r=0.5, view {view:.0f} deg, rel. RMS {fit.rel_rms:.2f}", fontsize=8)
    axes[0, 0].legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(out / "brdf_lobes_slices.png", dpi=110)
    plt.close(fig)

    (out / "brdf_lobes.md").write_text(markdown(s))
    (out / "brdf_lobes.json").write_text(json.dumps(s, indent=1))
    return s
