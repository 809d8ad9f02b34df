"""The lab's commands of `garment-render` (bench, speed, error-split and the figures: lobes,
brdf-lobes, area-lights), which the core's command line adds when this package is installed (the
`garment_render.commands` entry point; renderer/cli.py, lab_commands)."""

from __future__ import annotations

import importlib
import json
import time
from pathlib import Path

from renderer.errors import InvalidInputError
from renderer.presets import PRESET_NAMES


def add_commands(sub) -> None:
    """The lab's subcommands on the core's parser (`sub`: its subparsers)."""
    _bench_command(sub)
    _speed_command(sub)
    _error_split_command(sub)
    _figure_commands(sub)


def cmd_error_split(args) -> int:
    from .split import run

    if args.spp < 1 or args.rays < 1:
        raise InvalidInputError(f"--spp and --rays must be >= 1, got {args.spp} and {args.rays}")
    data = run(args.out, args.set, args.spp, args.rays, args.quick)
    print((args.out / "error_split.md").read_text())
    print(f"wrote {args.out / 'error_split.md'}, error_split.json, error_split.png ({data['wall_s'] / 60:.1f} min)")
    return 0


def cmd_speed(args) -> int:
    from .speed import LARGE_VARIANTS, markdown, run_speed

    if args.one_shot:
        from .one_shot import markdown as one_shot_markdown
        from .one_shot import run_one_shot

        if args.rounds < 1:
            raise InvalidInputError(f"--rounds must be positive, got {args.rounds}")
        print(one_shot_markdown(run_one_shot(args.out, args.rounds)))
        return 0

    size = args.size if args.size is not None else (1024 if args.large else 256)
    if args.rounds < 1 or size < 1 or args.min_triangles < 1:
        raise InvalidInputError(f"--rounds, --size and --min-triangles must be positive, got {args.rounds}, "
                                f"{size} and {args.min_triangles}")
    variants = LARGE_VARIANTS if args.large else None
    if args.equal_error and not args.large:
        raise InvalidInputError("--equal-error needs --large")
    if args.truth_spp < 1 or (args.workers is not None and args.workers < 2):
        raise InvalidInputError(f"--truth-spp must be positive and --workers at least 2, got {args.truth_spp} "
                                f"and {args.workers}")
    equal = {"truth_spp": args.truth_spp, "workers": args.workers} if args.equal_error else None
    result = run_speed(args.out, args.rounds, size, shared=not args.no_shared, large=args.large,
                       min_triangles=args.min_triangles, variants=variants, equal_error=equal)
    what = f", {result['triangles']} triangles ({result['garment_triangles']} in the garment)" if args.large else ""
    print(f"{result['device']}, {size}x{size}{what}, median of {args.rounds} frames per setting, "
          "settings taking turns (10th-90th percentile in brackets; GPU: GL timer queries, where meaningful):")
    print(markdown(result))
    if args.large:
        b = result["pem_build"]
        gpu = f", GPU {b['gpu_ms']:.2f} ms" if b["gpu_ms"] is not None else ""
        print(f"PEM set of {b['lights']} regions at {b['face_size']}^2 faces built in {b['wall_ms']:.1f} ms{gpu}")
    return 0


def cmd_bench(args) -> int:
    from .run import BenchConfig, run_bench

    # The side benchmarks: flag -> extra keyword arguments of garment_lab.<flag>.run, which writes
    # <flag>.json and <flag>.md.
    side = {"area": {}, "shadow_maps": {"preset_name": args.preset}, "sizes": {}, "views": {}, "materials": {},
            "energy": {}, "edges": {}, "fabrics": {}}
    for name, extra in side.items():
        if getattr(args, name):
            importlib.import_module(f"garment_lab.{name}").run(args.out, quick=args.quick, **extra)
            print(f"wrote {args.out}/{name}.json, {name}.md")
            return 0
    if args.broad and args.curve is not None:
        from .curve import curve_stem
        from .curve import run as trade_curve

        trade_curve(args.curve, args.out, size=args.size or 256)
        print(f"wrote {args.out}/{curve_stem(args.size or 256)}.json, .md, .png")
        return 0
    if args.broad and args.retime is not None:
        from .broad import retime

        retime(args.retime, args.out / "broad.json")
        print(f"wrote {args.out}/broad.json, broad.md")
        return 0
    if args.broad:
        from .broad import BroadConfig, run_broad

        cfg = BroadConfig.quick_config() if args.quick else BroadConfig()
        cfg.workers, cfg.cache = args.workers, str(args.reference_cache) if args.reference_cache else None
        if args.size is not None:
            cfg.sizes = (args.size,)
        run_broad(args.out, cfg)
        print(f"wrote {args.out}/broad.json, broad.md")
        return 0

    cfg = BenchConfig.quick_config() if args.quick else BenchConfig()
    if args.no_shared:
        cfg.shared = False
    run_bench(args.out, cfg)
    print(f"wrote {args.out}/bench.json, bench.md, pareto.png")
    if args.store:
        from renderer.presets.budget import MEASURED, write_table

        write_table(args.out / "bench.json")
        print(f"stored the measured table in {MEASURED}")
    return 0


def cmd_lobes(args) -> int:
    from .lobe_figures import write_lobe_report

    args.out.mkdir(parents=True, exist_ok=True)
    write_lobe_report(args.out, face_size=args.face_size)
    print(f"wrote {args.out}/lobes_fig4.png, lobes_fig5.png, lobes.md, lobes.json")
    return 0


def cmd_area_lights(args) -> int:
    from renderer.envmap import load_environment
    from renderer.lighting.area_lights import decompose, report

    from .area_figures import write_preview

    paths = list(args.env)
    if not paths:
        from .catalogue import MAPS
        from .scenes import shared_assets

        paths = [shared_assets() / "hdri" / m for m in MAPS]
    args.out.mkdir(parents=True, exist_ok=True)
    rows = {}
    lines = ["| map | area lights | largest (radius, share) | ambient share | ms |", "|---|---|---|---|---|"]
    for path in paths:
        env = load_environment(path, face_size=args.face_size, repair=True)
        t0 = time.perf_counter()
        dec = decompose(env.cube)
        rep = rows[Path(path).name] = report(dec, (time.perf_counter() - t0) * 1e3)
        write_preview(env.cube, dec, args.out / f"{Path(path).stem}.png", Path(path).name)
        top = ", ".join(f"{x['angular_radius_deg']:.1f} deg {x['energy_share']:.1%}" for x in rep["lights"][:3])
        lines.append(f"| {Path(path).name} | {len(rep['lights'])} | {top or '-'} | {rep['ambient_share']:.1%} | "
                     f"{rep['wall_ms']:.0f} |")
    (args.out / "area_lights.json").write_text(json.dumps(rows, indent=1))
    (args.out / "area_lights.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"wrote {args.out}/area_lights.md, area_lights.json and one preview PNG per map")
    return 0


def cmd_brdf_lobes(args) -> int:
    from .material_figures import markdown, write_brdf_lobe_report

    s = write_brdf_lobe_report(args.out)
    print(markdown(s))
    print(f"wrote {args.out}/brdf_lobes_fig7.png, brdf_lobes_slices.png, brdf_lobes.md, brdf_lobes.json")
    return 0


def _bench_command(sub) -> None:
    """The lab's benchmarks (lab/garment_lab)."""
    b = sub.add_parser("bench", help="sweep the quality knobs against the reference; write bench.json/md, pareto.png")
    b.add_argument("--quick", action="store_true", help="a reduced sweep that finishes in minutes on 2 cores")
    b.add_argument("--no-shared", action="store_true", help="bundled scene only (skip ../shared/assets)")
    b.add_argument("--out", type=Path, default=Path("out/bench"))
    b.add_argument("--area", action="store_true",
                   help="median cut against area lights (and auto) on every shared map, at equal light count and "
                        "equal frame time (lab/garment_lab/area.py)")
    b.add_argument("--shadow-maps", action="store_true",
                   help="balanced's main shadow maps at 256^2, 384^2 and 512^2 with the casters at 1/4, 1/2 and full "
                        "detail, on the broad catalogue's 256 x 256 scenes, tuning and held-out apart "
                        "(lab/garment_lab/shadow_maps.py)")
    b.add_argument("--preset", choices=PRESET_NAMES, default="balanced",
                   help="the preset --shadow-maps varies (default balanced)")
    b.add_argument("--sizes", action="store_true",
                   help="balanced at 256, 512 and 1024 pixels a side against references of each size, and with its "
                        "shadow maps following the image (lab/garment_lab/sizes.py)")
    b.add_argument("--views", action="store_true",
                   help="a turntable's views and colourways in one call against one by one: what sharing the shadow "
                        "pass saves (lab/garment_lab/views.py)")
    b.add_argument("--edges", action="store_true",
                   help="the ways to anti-alias (none, the renderer's 4 samples a pixel, 2 x 2 supersampling) at fast "
                        "and balanced: silhouette and interior error against references that integrate each pixel's "
                        "area, and frame time, on the held-out maps (lab/garment_lab/edges.py)")
    b.add_argument("--fabrics", action="store_true",
                   help="five U3M fabrics of our making (print, denim twill, satin, voile, velvet) on the draped dress "
                        "under held-out maps, against the reference and against each one's plain twin: error and "
                        "frame time (lab/garment_lab/fabrics.py)")
    b.add_argument("--materials", action="store_true",
                   help="the physically based fabrics (1 and 2 fitted lobes) against the reference beside the Phong "
                        "fabric, on tuning and held-out maps apart (lab/garment_lab/materials.py)")
    b.add_argument("--energy", action="store_true",
                   help="each physically based material's energy and error against the reference on a sphere: "
                        "roughness 0.1-1, dielectric and metal, sheen, under a uniform map, one small light in front "
                        "and behind, and coloured windows (lab/garment_lab/energy.py; a minute here)")
    b.add_argument("--broad", action="store_true",
                   help="the presets on every shared map x 3 garments x 3 fabrics x 2 views, a tuning and a held-out "
                        "set reported apart, with the artefact share (writes broad.json/md, which give each set's "
                        "wall time; --size 256: the held-out set first, in about twenty minutes from a cold cache on "
                        "two cores)")
    b.add_argument("--workers", type=int, help="with --broad: reference processes (default: one per core)")
    b.add_argument("--size", type=int, choices=[128, 256, 512],
                   help="with --broad: only the scenes of this size (default both the 128x128 sweep and the 256x256 "
                        "subset where the targets are judged; 512: that subset's held-out scenes at 512x512, where "
                        "the equal-error targets are judged again)")
    b.add_argument("--reference-cache", type=Path,
                   help="with --broad: the references' folder (default: $GARMENT_RENDER_REFERENCE_CACHE, else "
                        "~/.cache/garment-render/references)")
    b.add_argument("--retime", type=Path, metavar="BROAD_JSON",
                   help="with --broad: a stored run's frame times and the tracer's measured again on this machine, "
                        "its errors kept (garment_lab.broad.retime; for code that renders the same images)")
    b.add_argument("--curve", type=Path, metavar="BROAD_JSON",
                   help="with --broad: the trade curve of a stored run: frame time against held-out error for every "
                        "preset and knob variant beside the tracer's at 4-1024 samples (lab/garment_lab/curve.py; "
                        "--size: 256 by default)")
    b.add_argument("--store", action="store_true",
                   help="store the measured table in the package: budgets (--frame-budget-ms, --error-budget) choose from it")
    b.set_defaults(func=cmd_bench)


def _speed_command(sub) -> None:
    sp = sub.add_parser("speed", help="frame times of the presets side by side (settings take turns, frame by frame)")
    sp.add_argument("--rounds", type=int, default=15, help="frames per setting and scene")
    sp.add_argument("--size", type=int, help="image side (default 256; 1024 with --large)")
    sp.add_argument("--no-shared", action="store_true", help="bundled scene only (skip ../shared/assets)")
    sp.add_argument("--large", action="store_true",
                    help="the GPU target's scene instead: the newton shirt subdivided to at least --min-triangles "
                         "on its dress form under the hard sun, positions uploaded every frame: balanced, fast, "
                         "accurate and balanced with either lighting pass and either place for the normals, with the "
                         "PEM set's build time (needs ../shared/assets)")
    sp.add_argument("--min-triangles", type=int, default=100_000, help="the --large garment's least triangle count")
    sp.add_argument("--one-shot", action="store_true",
                    help="the wall time of whole render commands instead, each a new process: on a machine's first "
                         "run, on a map not rendered before and on one rendered before (lab/garment_lab/one_shot.py; "
                         "--out: the folder for one_shot.json and .md; --rounds: rounds, e.g. 3)")
    sp.add_argument("--equal-error", action="store_true",
                    help="with --large: the reference's samples and time to match each preset's error (a truth of "
                         "--workers renders of --truth-spp samples, one process per core; minutes at 1024x1024)")
    sp.add_argument("--truth-spp", type=int, default=128, help="samples per technique of each truth render")
    sp.add_argument("--workers", type=int, help="reference processes (default: one per core)")
    sp.add_argument("--out", type=Path, help="write the medians and ratios as JSON")
    sp.set_defaults(func=cmd_speed)


def _error_split_command(sub) -> None:
    es = sub.add_parser("error-split", help="where each preset's error comes from: the lights alone, the same "
                                            "lights with exact visibility (rays), the shadow maps, per pixel class "
                                            "(needs ../shared/assets; error_split.md, .json, .png)")
    es.add_argument("--set", choices=("held-out", "tuning"), default="held-out", help="the broad catalogue's maps")
    es.add_argument("--spp", type=int, default=64, help="samples per technique of each of the four references")
    es.add_argument("--rays", type=int, default=8, help="exact visibility's rays per light and pixel")
    es.add_argument("--quick", action="store_true", help="one scene, fast and balanced (a check, minutes)")
    es.add_argument("--out", type=Path, default=Path("out/error-split"))
    es.set_defaults(func=cmd_error_split)


def _figure_commands(sub) -> None:
    """The lab's figures: the paper's lobes, the physically based lobes' fit, the area lights."""
    lo = sub.add_parser("lobes", help="reproduce the paper's Figures 4 and 5 (lobe cross sections and errors)")
    lo.add_argument("--out", type=Path, default=Path("out/lobes"))
    lo.add_argument("--face-size", type=int, default=128)
    lo.set_defaults(func=cmd_lobes)
    bl = sub.add_parser("brdf-lobes", help="the physically based BRDFs' lobe fit: rel. RMS against view elevation "
                                          "and lobe count (Kautz and McCool's Figure 7), and the fitted slices")
    bl.add_argument("--out", type=Path, default=Path("out/brdf-lobes"))
    bl.set_defaults(func=cmd_brdf_lobes)
    al = sub.add_parser("area-lights", help="Arbree, Walter and Bala's area lights of environment maps: the lights "
                                           "found, the ambient share, and a preview per map (default: every shared map)")
    al.add_argument("--env", type=Path, action="append", default=[], help="environment map (.exr/.hdr); repeatable")
    al.add_argument("--face-size", type=int, default=128, help="the cube the lights are found on (the PEM face size)")
    al.add_argument("--out", type=Path, default=Path("out/area-lights"))
    al.set_defaults(func=cmd_area_lights)
