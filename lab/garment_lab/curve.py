"""`garment-render bench --broad --curve BROAD_JSON`: the trade curve of a stored broad run.

Frame time against error over one set of scenes (the held-out ones at 256 x 256 by default) for every
preset and knob variant the run measured, beside the Monte Carlo tracer's at 4-1024 samples on the
same scenes and cores. The tracer's points follow the broad benchmark's model (lab/garment_lab/broad.py):
its error at N samples is the pair's floor / sqrt(2) x sqrt(reference spp / N) (it is unbiased, its
relMSE falls as 1/N), its time the run's measured rate with the samples split over every core
(`broad.tracer_time_ms`, with the setup a retimed run measured). Each setting is judged against both
methods: it is on the lower envelope when nothing else is both faster and more accurate, and the
tracer's time at its error says by how much it leads (or trails) the tracer.

Medians and worsts are over the scenes, for time and error alike (a setting's median time and median
error need not come from one scene).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .broad import error_at_spp, tracer_time_ms

TRACER_SPP = (4, 8, 16, 32, 64, 128, 256, 512, 1024)


def _tracer_time_at(error: float, tracer: list[dict]) -> float | None:
    """The tracer's median time at a median error, interpolated in log-log between its points (None
    outside them)."""
    errs = np.log([p["rel_rmse_median"] for p in tracer])
    times = np.log([p["time_ms_median"] for p in tracer])
    e = np.log(error)
    if not errs.min() <= e <= errs.max():
        return None
    order = np.argsort(errs)
    return float(np.exp(np.interp(e, errs[order], times[order])))


def trade_curve(data: dict, size: int = 256, which: str = "held-out") -> dict:
    """The curve of a stored broad run's rows of one size and set: a point per setting, the tracer's
    points, and per setting whether it is on the lower envelope and the tracer's time at its error."""
    rows = [r for r in data["rows"] if r["size"] == size and r["set"] == which]
    if not rows:
        raise ValueError(f"the run has no {which} rows at {size} x {size}")
    retimed = data.get("retimed") or {}
    cores = int(retimed.get("cores") or data["machine"]["cores"])
    setup = {name: rate["setup_ms"] for name, rate in (retimed.get("tracer") or {}).items()}
    points = []
    for setting in sorted({r["preset"] for r in rows}):
        sel = [r for r in rows if r["preset"] == setting]
        ms, err = np.array([r["frame_ms"] for r in sel]), np.array([r["rel_rmse"] for r in sel])
        points.append({"setting": setting, "scenes": len(sel), "time_ms_median": float(np.median(ms)),
                       "time_ms_max": float(ms.max()), "rel_rmse_median": float(np.median(err)),
                       "rel_rmse_max": float(err.max())})
    scenes = {r["scene"]: r for r in rows}   # one row per scene carries its truth's floor and rate
    tracer = []
    for spp in TRACER_SPP:
        err = np.array([error_at_spp(spp, r["ref_noise_rel_rmse"], r["ref_spp"]) for r in scenes.values()])
        ms = np.array([tracer_time_ms(spp, setup.get(name, 0.0), r["ref_ms_per_spp"], cores)
                       for name, r in scenes.items()])
        tracer.append({"spp": spp, "time_ms_median": float(np.median(ms)), "time_ms_max": float(ms.max()),
                       "rel_rmse_median": float(np.median(err)), "rel_rmse_max": float(err.max())})
    for p in points:
        others = [q for q in points if q is not p]
        faster_and_better = [q["setting"] for q in others if q["time_ms_median"] <= p["time_ms_median"]
                             and q["rel_rmse_median"] <= p["rel_rmse_median"]
                             and (q["time_ms_median"], q["rel_rmse_median"]) != (p["time_ms_median"], p["rel_rmse_median"])]
        at = _tracer_time_at(p["rel_rmse_median"], tracer)
        p["tracer_ms_at_its_error"] = at
        p["x_tracer"] = None if at is None else at / p["time_ms_median"]
        p["dominated_by"] = faster_and_better + (["tracer"] if at is not None and at < p["time_ms_median"] else [])
        p["on_envelope"] = not p["dominated_by"]
    machine = (retimed.get("machine") or data["machine"])
    return {"size": size, "set": which, "cores": cores, "machine": machine, "points": points, "tracer": tracer,
            "presets_digest": data.get("presets_digest"), "run_date": data["machine"]["date"]}


def markdown(curve: dict, source: str) -> str:
    m = curve["machine"]
    size_flag = "" if curve["size"] == 256 else f" --size {curve['size']}"
    lines = [f"# Trade curve: {curve['set']} scenes at {curve['size']} x {curve['size']}", "",
             f"Made by `garment-render bench --broad --curve {source}{size_flag}` from that stored run (errors of "
             f"{curve['run_date']}, times on {m['gl_renderer']}, {curve['cores']} cores, {m['date']}); the tracer's "
             "points follow the run's model (lab/garment_lab/curve.py). Medians (worst) over the scenes.", "",
             f"![time against error]({curve_stem(curve['size'])}.png)", "",
             "| setting | frame ms | rel. RMSE | tracer's time at its error | on the lower envelope |",
             "|---|---|---|---|---|"]
    for p in sorted(curve["points"], key=lambda p: p["time_ms_median"]):
        x = "beyond the tracer's points" if p["x_tracer"] is None else f"{p['tracer_ms_at_its_error']:.0f} ms ({p['x_tracer']:.1f}x)"
        env = "yes" if p["on_envelope"] else "no: " + ", ".join(p["dominated_by"])
        lines.append(f"| {p['setting']} | {p['time_ms_median']:.0f} ({p['time_ms_max']:.0f}) | "
                     f"{p['rel_rmse_median']:.3f} ({p['rel_rmse_max']:.3f}) | {x} | {env} |")
    lines += ["", "| tracer spp | ms | rel. RMSE |", "|---|---|---|"]
    for t in curve["tracer"]:
        lines.append(f"| {t['spp']} | {t['time_ms_median']:.0f} ({t['time_ms_max']:.0f}) | "
                     f"{t['rel_rmse_median']:.3f} ({t['rel_rmse_max']:.3f}) |")
    return "\n".join(lines) + "\n"


def plot(curve: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5.0))
    t = curve["tracer"]
    ax.plot([p["time_ms_median"] for p in t], [p["rel_rmse_median"] for p in t], "-o", color="0.4", ms=3,
            label="Monte Carlo tracer (median)")
    for p in t:
        ax.annotate(f"{p['spp']}", (p["time_ms_median"], p["rel_rmse_median"]), fontsize=7, color="0.4",
                    xytext=(3, 3), textcoords="offset points")
    for p in curve["points"]:
        preset = ":" not in p["setting"]
        ax.plot([p["time_ms_median"]], [p["rel_rmse_median"]], "o" if preset else ".", ms=7 if preset else 5,
                color="C0" if p["on_envelope"] else "C3")
        ax.plot([p["time_ms_median"], p["time_ms_max"]], [p["rel_rmse_median"], p["rel_rmse_max"]], ":", lw=0.6,
                color="C0" if p["on_envelope"] else "C3")
        if preset:
            ax.annotate(p["setting"], (p["time_ms_median"], p["rel_rmse_median"]), fontsize=8,
                        xytext=(4, -10), textcoords="offset points")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("frame time, ms (median over scenes; dotted: to the worst)")
    ax.set_ylabel("rel. RMSE against the reference")
    ax.set_title(f"{curve['set']} scenes, {curve['size']} x {curve['size']}, {curve['cores']} cores "
                 f"({curve['machine']['gl_renderer'].split(' (')[0]}); blue: on the lower envelope", fontsize=9)
    ax.legend(fontsize=8)
    ax.grid(True, which="both", lw=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def curve_stem(size: int) -> str:
    """The curve's file name without its suffix: trade_curve at 256 x 256, trade_curve-<size> else."""
    return "trade_curve" if size == 256 else f"trade_curve-{size}"


def run(source: Path, out_dir: Path, size: int = 256, which: str = "held-out") -> dict:
    """The curve of the stored run at `source`, written to out_dir (`curve_stem`: .json, .md, .png)."""
    data = json.loads(Path(source).read_text())
    curve = trade_curve(data, size, which)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = curve_stem(size)
    (out_dir / f"{stem}.json").write_text(json.dumps(curve, indent=1))
    (out_dir / f"{stem}.md").write_text(markdown(curve, str(source)))
    plot(curve, out_dir / f"{stem}.png")
    return curve
