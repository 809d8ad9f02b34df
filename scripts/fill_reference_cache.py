"""Renders the broad benchmark's missing references into the reference cache ahead of its stored runs
(`garment-render bench --broad`, the edges bench), smallest images first, the held-out set before the
tuning set; each reference is kept as soon as it is made, so a run stopped half-way is taken up where
it ended. A change to the reference's code (lab/garment_lab/broad.py, `_REFERENCE_SOURCES`) voids the
cache: fill it after the last such change, on a machine left to it (cold: hours; `--workers 1` leaves a
core free).

    python scripts/fill_reference_cache.py [--sizes 128,256,512] [--workers N] [--dry-run] [--rekey-from DIGEST]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "lab")]   # this checkout's product and lab, wherever it is

from garment_lab.broad import (  # noqa: E402
    SEEDS,
    BroadConfig,
    ReferenceCache,
    bench_scenes,
    default_cache_dir,
    ensure_references,
)
from garment_lab.catalogue import split  # noqa: E402


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="128,256,512", help="image sizes whose scenes to fill (default all)")
    ap.add_argument("--workers", type=int, default=len(os.sched_getaffinity(0)), help="reference processes")
    ap.add_argument("--dry-run", action="store_true", help="count the missing references and stop")
    ap.add_argument("--rekey-from", metavar="DIGEST",
                    help="first rename the references made under this reference-code digest to today's (a change "
                         "that moved the reference's code, not what it computes: garment_lab.broad, _REFERENCE_SOURCES)")
    args = ap.parse_args(argv)
    sizes = {int(s) for s in args.sizes.split(",")}
    cfg = BroadConfig()
    cache = ReferenceCache(default_cache_dir(), pixel_samples=cfg.pixel_samples)
    sets = split()
    if args.rekey_from:
        print(f"renamed {cache.rekey(bench_scenes(), cfg.spp_of, args.rekey_from)} references made under "
              f"{args.rekey_from[:12]} to today's code ({cache.code[:12]})", flush=True)
    todo = sorted((s for s in bench_scenes() if s.size in sizes),
                  key=lambda s: (s.size, sets[s.map] != "held-out", s.map, s.garment))
    missing = [s for s in todo if any(cache.get(s, cfg.spp_of(s), seed) is None for seed in SEEDS)]
    print(f"{len(todo)} scenes at {sorted(sizes)} px, {len(missing)} with a reference missing "
          f"(cache {cache.folder})", flush=True)
    if args.dry_run:
        return 0
    for size in sorted(sizes):
        part = [s for s in missing if s.size == size]
        if part:
            print(f"{size} px: {len(part)} scenes", flush=True)
            ensure_references(part, cfg.spp_of, cache, max(1, args.workers), log=lambda m: print(m, flush=True))
    return 0


if __name__ == "__main__":
    sys.exit(main())
