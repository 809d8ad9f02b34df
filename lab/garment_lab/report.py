"""Benchmark outputs: the Markdown table (with the paper's Figure 8 memory beside ours) and the
Pareto plot of error against frame time."""

from __future__ import annotations

import os
import platform
import time
from pathlib import Path

import numpy as np

from renderer.reference.metrics import REL_MSE_EPS

MB = 1 << 20


def machine_info(gl) -> dict:
    """The machine a benchmark ran on, named in its report: the GL renderer, the CPU, its cores."""
    return {"gl_renderer": gl.renderer_name, "gl_version": gl.version, "cpu": platform.processor() or platform.machine(),
            "cores": len(os.sched_getaffinity(0)), "python": platform.python_version(), "date": time.strftime("%Y-%m-%d")}


def paper_pem_mb(n_regions: int, face_size: int) -> float:
    """Knuth et al. Fig. 8: 1.5 MB per PEM at 128^2 faces (RGBA16F with MIP maps), scaling with area."""
    return 1.5 * n_regions * (face_size / 128) ** 2


def paper_vsm_mb(n_lights: int, size: int) -> float:
    """Knuth et al. Fig. 8: one RG16F VSM of size^2 per light (4 bytes a texel)."""
    return 4.0 * size * size * n_lights / MB


# The speed/accuracy issue's targets on this CPU, at the balanced preset (on the newton shirt scenes;
# the other scenes are shown against the same numbers): (column, row value, bound, "<=" or ">=").
TARGETS = [("rel. RMSE", lambda r: r.rel_rmse, 0.05, "<="),
           ("mean HDR-FLIP", lambda r: r.flip, 0.05, "<="),
           ("frame ms", lambda r: r.frame_ms, 100.0, "<="),
           ("x reference at equal error", lambda r: r.speedup_vs_reference, 10.0, ">="),
           ("PEM build ms", lambda r: r.pem_build_ms, 1000.0, "<="),
           ("PEM MB / paper", lambda r: r.pem_bytes / MB / paper_pem_mb(r.settings["lights"], r.settings["face_size"]),
            1.0, "<="),
           # Shadow maps: reported beside the paper (the memory target is stated at the same region
           # count and PEM face size); above it by two shadow groups' float32 moments (4x), a blur's scratch array and
           # the small lights' larger maps.
           ("VSM MB / paper", lambda r: r.shadow_bytes / MB / paper_vsm_mb(r.settings["lights"], r.settings["shadow_size"]),
            1.0, "report")]


def _against(value, bound: float, sense: str, beyond_ms: float | None = None, frame_ms: float = 1.0) -> str:
    if sense == "report":
        return f"{value:.3g}"
    if value is None:   # the reference's most samples do not reach this error, or no value
        if beyond_ms is None:
            return "n/a"
        value = beyond_ms / frame_ms
        return f"> {value:.3g} ({'met' if value >= bound else 'unknown'}: beyond the reference's ladder)"
    met = value <= bound if sense == "<=" else value >= bound
    factor = value / bound if sense == "<=" else bound / max(value, 1e-300)
    return f"{value:.3g} ({'met' if met else f'missed, {factor:.2f}x'})"


def target_lines(rows) -> list[str]:
    """A table of each scene's balanced row against the targets: met, or missed by what factor. The
    frame time here is the sweep's median of a few frames; `garment-render speed` times the presets
    side by side, which is the speed target's measure."""
    balanced = [r for r in rows if r.knob == "balanced"]
    if not balanced:
        return []
    lines = ["## Targets at the balanced preset", "",
             "| scene | " + " | ".join(f"{name} ({'beside the paper' if sense == 'report' else f'{sense} {bound:g}'})"
                                         for name, _, bound, sense in TARGETS) + " |",
             "|---|" + "---|" * len(TARGETS)]
    for r in balanced:
        top = r.extra.get("ref_ladder_top_ms")   # only the reference column can be beyond its ladder
        lines.append(f"| {r.scene} | " + " | ".join(
            _against(get(r), bound, sense, top if name.startswith("x reference") else None, r.frame_ms)
            for name, get, bound, sense in TARGETS) + " |")
    lines += ["", "The frame time of this table is the sweep's median of a few frames; `garment-render speed` "
              "times the presets side by side (the speed target's measure).", ""]
    return lines


def pareto_front(times: np.ndarray, errors: np.ndarray) -> np.ndarray:
    """Indices of the settings no other setting beats in both frame time and error, by time."""
    order = np.lexsort((errors, times))
    front, best = [], np.inf
    for i in order:
        if errors[i] < best:
            front.append(i)
            best = errors[i]
    return np.array(front, int)


def _artefacts(r) -> str:
    """The artefact share of a row (`reference.artefact_share`), kept in its extra (rows stored before
    it was measured have none)."""
    share = r.extra.get("artefact_share")
    return "-" if share is None else f"{100 * share:.2f} %"


def write_markdown(path: Path, rows, machine: dict, cfg, refused: list[dict] = ()) -> None:
    """The sweep's report: a table per scene, the settings this machine refused under it (run.bench_scene),
    then the targets at the balanced preset."""
    lines = [f"# Benchmark ({'quick' if cfg.quick else 'full'})", "",
             f"Made by `garment-render bench{' --quick' if cfg.quick else ''}` (lab/garment_lab/run.py): every knob "
             "varied alone from the balanced preset of the preset files of the day (bench.json records their digest).",
             "",
             f"Machine: {machine['cpu']}, OpenGL: {machine['gl_renderer']} ({machine['gl_version']}), "
             f"date {machine['date']}. Image {cfg.size}x{cfg.size}; frame time = median of {cfg.frames} frames "
             f"after a warm-up frame; reference: the mean of two independent renders of {cfg.ref_spp} spp.", "",
             "Errors are in linear HDR over the garment and body pixels against the Monte Carlo reference "
             f"(rel. RMSE with eps = {REL_MSE_EPS:g} on images scaled to a mean of 1, renderer/reference/metrics.py; "
             "mean HDR-FLIP; artefacts: the share of judged pixels more than 2x or under 0.5x the truth's luminance, "
             "reference/metrics.py); the reference's noise floor (its two renders against each other: what a perfect "
             "renderer would score against one of them; the mean's own rel. RMSE is about half of it) is given "
             "per scene.", ""]
    for scene in dict.fromkeys(r.scene for r in rows):
        rs = [r for r in rows if r.scene == scene]
        lines += [f"## {scene} ({rs[0].env})", "",
                  f"Reference noise floor: rel. RMSE {rs[0].ref_noise_rel_rmse:.4f}, mean HDR-FLIP {rs[0].ref_noise_flip:.4f}.", "",
                  "| knob | value | mode | frame ms | shadow | blur | geometry | shading | PEM build ms | PEM MB (paper) | VSM MB (paper) "
                  "| rel. RMSE | FLIP | artefacts | reference at equal error |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in rs:
            s = r.settings
            eq = (f"{r.ref_equal_error_spp} spp, {r.ref_equal_error_ms:.0f} ms ({r.speedup_vs_reference:.1f}x)"
                  if r.ref_equal_error_spp else "not reached by the ladder")
            lines.append(
                f"| {r.knob} | {r.value} | {r.mode} | {r.frame_ms:.1f} | {r.stages_ms.get('shadow_maps', 0):.1f} | "
                f"{r.stages_ms.get('blur', 0):.1f} | {r.stages_ms.get('geometry', 0):.1f} | {r.stages_ms.get('shading', 0):.1f} | {r.pem_build_ms:.0f} | "
                f"{r.pem_bytes / MB:.1f} ({paper_pem_mb(s['lights'], s['face_size']):.1f}) | "
                f"{r.shadow_bytes / MB:.1f} ({paper_vsm_mb(s['lights'], s['shadow_size']):.1f}) | "
                f"{r.rel_rmse:.4f} | {r.flip:.4f} | {_artefacts(r)} | {eq} |")
        lines.append("")
        no = [x for x in refused if x["scene"] == scene]
        if no:
            lines += ["Not run on this machine (the renderer refused them before drawing):", ""]
            lines += [f"- {x['knob']} = {x['value']} [{x['mode']}]: {x['why']}" for x in no]
            lines.append("")
    lines += target_lines(rows)
    lines += ["VSM memory: moments are 32-bit floats (RG32F), a layer per light and shadow group (the garment's "
              "and the body's), four times the paper's RG16F maps at the same size and count; a setting that blurs "
              "(blur scale > 0) adds a scratch array of the same size (eight times), "
              "and small lights' maps are small_light_scale times larger per side.", ""]
    path.write_text("\n".join(lines))


def write_pareto(path: Path, rows) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    scenes = list(dict.fromkeys(r.scene for r in rows))
    fig, axes = plt.subplots(1, len(scenes), figsize=(5 * len(scenes), 4.2), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        rs = [r for r in rows if r.scene == scene]
        t = np.array([r.frame_ms for r in rs])
        e = np.array([r.rel_rmse for r in rs])
        method = np.array([r.mode == "full" for r in rs])
        ax.scatter(t[method], e[method], s=18, label="PEM + VSM settings")
        ax.scatter(t[~method], e[~method], s=30, marker="s", label="baselines")
        for r, ti, ei in zip(rs, t, e):
            label = r.value if r.knob == "baseline" else (r.value if "=" in str(r.value) else f"{r.knob}={r.value}")
            ax.annotate(label, (ti, ei), fontsize=6, xytext=(3, 2), textcoords="offset points")
        front = pareto_front(t, e)
        ax.plot(t[front], e[front], "k--", lw=1, label="Pareto front")
        ax.axhline(rs[0].ref_noise_rel_rmse, color="grey", lw=0.8, ls=":", label="reference noise floor")
        ax.set_xscale("log")
        ax.set_yscale("log")
        # Plain numbers on the axes; minor ticks unlabelled (log-scale minor labels overlap).
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
            axis.set_major_formatter(matplotlib.ticker.FormatStrFormatter("%g"))
            axis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.set_xlabel("median frame time (ms)")
        ax.set_ylabel("relative RMSE vs Monte Carlo reference")
        ax.set_title(scene, fontsize=9)
        ax.legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
