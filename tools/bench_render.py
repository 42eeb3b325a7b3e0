"""Frames per second of ``rtdefocus.render`` against the number of local worker processes.

Renders the same film (the quick clip of ``rtdefocus eval --video``, with a tone) through the
simulator's oracle calibration with 1, 2, … workers, each run from an empty work folder, and
reports wall-clock frames per second (worker start-up and the final mux included) and the
speed-up over one worker. Writes JSON named by commit and device.

    python tools/bench_render.py --size 400x300 --workers 1 2
    python tools/bench_render.py --scheduler tcp://head:8786       # a Dask cluster instead
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="400x300", help="projector and film size (default 400x300)")
    ap.add_argument("--frames", type=int, default=30, help="film length (the quick clip, cut)")
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--scheduler", help="a Dask scheduler address: one run there as well")
    ap.add_argument("--chunk-frames", type=int, default=8)
    ap.add_argument("--quality", default="high")
    ap.add_argument("--repeat", type=int, default=1, help="runs per worker count (median)")
    ap.add_argument("-o", "--out", default=None,
                    help="JSON file (default bench_render_<commit>_<device>.json)")
    args = ap.parse_args(argv)

    import rtdefocus as rd
    from rtdefocus.film import DEFAULT_OVERLAP, render
    from rtdefocus.film.media import write_film
    from rtdefocus.sim import oracle_calibration
    from rtdefocus.study.eval_video import QUICK_SEGMENTS, make_clip
    from rtdefocus.study.machine import machine_info

    w, h = (int(v) for v in args.size.split("x"))
    tmp = Path(tempfile.mkdtemp(prefix="bench_render_"))
    setup, film = tmp / "setup.npz", tmp / "film.mp4"
    procam = rd.sim.VirtualProCam("cubicle", projector_size=(w, h), camera_size=(w * 8 // 5, h * 8 // 5))
    oracle_calibration(procam).save(setup)
    write_film(film, [f for _, f in make_clip((w, h), QUICK_SEGMENTS)][:args.frames], fps=30)

    runs = [("local", n) for n in args.workers]
    if args.scheduler:
        runs.append(("dask", args.scheduler))
    rows = []
    for kind, n in runs:
        times = []
        for r in range(args.repeat):
            out = tmp / f"out_{kind}_{n}_{r}.mp4".replace("/", "_").replace(":", "_")
            t0 = time.perf_counter()
            res = render(setup, film, out, quality=args.quality, chunk_frames=args.chunk_frames,
                         overlap=DEFAULT_OVERLAP, workers=n if kind == "local" else 0,
                         scheduler=n if kind == "dask" else None, work=tmp / f"work_{kind}_{r}")
            times.append(time.perf_counter() - t0)
        t = sorted(times)[len(times) // 2]
        rows.append({"scheduler": kind, "workers": n, "seconds": t, "fps": res.frames / t,
                     "frames": res.frames, "chunks": res.chunks})
        print(f"{kind:5s} workers={n}: {res.frames} frames in {t:.1f} s = {res.frames / t:.2f} "
              "frames/s", flush=True)
    base = next((r["fps"] for r in rows if r["scheduler"] == "local" and r["workers"] == 1), None)
    for r in rows:
        r["speedup"] = r["fps"] / base if base else None
    machine = machine_info()
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    device = str(machine.get("device", "cpu")).split(" (")[0].replace(" ", "_")[:40]
    path = Path(args.out or f"bench_render_{commit}_{device}.json")
    path.write_text(json.dumps({"size": [w, h], "chunk_frames": args.chunk_frames,
                                "overlap": DEFAULT_OVERLAP, "quality": args.quality,
                                "machine": machine, "commit": commit, "runs": rows}, indent=1))
    print("| workers | frames/s | speed-up |\n| --- | --- | --- |")
    for r in rows:
        label = r["workers"] if r["scheduler"] == "local" else f"dask {r['workers']}"
        print(f"| {label} | {r['fps']:.2f} | {r['speedup']:.2f}x |" if r["speedup"] else
              f"| {label} | {r['fps']:.2f} | - |")
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
