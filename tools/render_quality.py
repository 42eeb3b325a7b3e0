"""What a rendered film keeps of the compensation: the seams between chunks and the encoding.

On the clip of ``rtdefocus eval --video`` (written to a film with a sine tone), through the
simulator's oracle calibration:

1. the frames compensated serially in memory (one Compensator, warm start, the render budget);
2. ``rtdefocus.render`` of the same film in chunks (``--chunk-frames``, lossless ``archive``
   quality), decoded: per frame, the camera view's PSNR against the serial frame's (the seams);
3. the serial frames encoded at each quality and decoded: per frame, the camera view's PSNR
   against the uncompressed frame's (the cost of the encoding).

Camera views are noiseless captures scored inside the display rectangle against the sharp
capture of the same warp, as ``eval --video`` scores them.

    python tools/render_quality.py --size 800x600 -o render_quality.json
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", default="800x600", help="projector and clip size (default 800x600)")
    ap.add_argument("--quick", action="store_true", help="the 30-frame quick clip")
    ap.add_argument("--chunk-frames", type=int, default=16)
    ap.add_argument("--overlap", type=int, default=None)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("-o", "--output", default="render_quality.json")
    args = ap.parse_args(argv)

    import rtdefocus as rd
    from rtdefocus.film import DEFAULT_OVERLAP, QUALITIES, RENDER_ITERATIONS, render
    from rtdefocus.film.media import ChunkWriter, decode_rgb, probe, read_frames, write_film
    from rtdefocus.sim import oracle_calibration
    from rtdefocus.study.eval_video import QUICK_SEGMENTS, SEGMENTS, make_clip
    from rtdefocus.study.scores import camera_view, psnr, rect_mask

    w, h = (int(v) for v in args.size.split("x"))
    overlap = DEFAULT_OVERLAP if args.overlap is None else args.overlap
    procam = rd.sim.VirtualProCam("cubicle", projector_size=(w, h), camera_size=(w * 8 // 5, h * 8 // 5),
                                  noise=0.0)
    calib = oracle_calibration(procam)
    clip = make_clip((w, h), QUICK_SEGMENTS if args.quick else SEGMENTS)
    segments = [s for s, _ in clip]
    tmp = Path(tempfile.mkdtemp(prefix="render_quality_"))
    setup, film = tmp / "setup.npz", tmp / "film.mp4"
    calib.save(setup)
    write_film(film, [f for _, f in clip])
    info = probe(film)
    inputs = list(read_frames(info, 0, info.n_frames))

    comp = rd.Compensator(calib)
    t0 = time.perf_counter()
    serial = [comp.compensate(im, iterations=RENDER_ITERATIONS) for im in inputs]
    t_serial = time.perf_counter() - t0
    print(f"serial: {len(serial)} frames in {t_serial:.1f} s", flush=True)

    t0 = time.perf_counter()
    res = render(setup, film, tmp / "out.mkv", quality="archive", workers=args.workers,
                 chunk_frames=args.chunk_frames, overlap=overlap)
    t_render = time.perf_counter() - t0
    chunked = list(decode_rgb(res.output))
    print(f"render: {res.chunks} chunks, {args.workers} workers, {t_render:.1f} s", flush=True)

    encoded = {}
    for q in ("high", "compatible"):
        path = tmp / f"serial_{q}.nut"
        with ChunkWriter(path, QUALITIES[q], info.fps, (w, h)) as wr:
            for f in serial:
                wr.write(f)
        encoded[q] = (list(decode_rgb(path)), path.stat().st_size)

    rect = calib.display_rect(info.size)
    mask = rect_mask(rect, (procam.camera_size[1], procam.camera_size[0]))
    seams = {c * args.chunk_frames for c in range(1, res.chunks)}
    rows = []
    for i, image in enumerate(inputs):
        warped = comp.warp(image)
        ref = camera_view(procam, calib, warped, sharp=True)

        def score(frame, ref=ref):
            return psnr(camera_view(procam, calib, frame), ref, mask)

        row = {"frame": i, "segment": segments[i], "seam": i in seams, "geometry": score(warped),
               "serial": score(serial[i]), "chunked": score(chunked[i]),
               "max_code_diff": int(np.abs(serial[i].astype(int) - chunked[i]).max())}
        for q, (frames, _) in encoded.items():
            row[q] = score(frames[i])
        rows.append(row)
    d_seam = [r["chunked"] - r["serial"] for r in rows]
    summary = {"frames": len(rows), "chunks": res.chunks, "chunk_frames": args.chunk_frames,
               "overlap": overlap, "size": [w, h], "iterations": RENDER_ITERATIONS,
               "serial_s": t_serial, "render_s": t_render, "workers": args.workers,
               "seam_max_abs_db": float(np.max(np.abs(d_seam))),
               "seam_frames_max_abs_db": float(max(abs(d) for d, r in zip(d_seam, rows, strict=True)
                                                   if r["seam"])) if seams else 0.0,
               "gain_serial_db": float(np.mean([r["serial"] - r["geometry"] for r in rows]))}
    for q, (_, size) in encoded.items():
        d = [r[q] - r["serial"] for r in rows]
        summary[q] = {"mean_db": float(np.mean(d)), "worst_db": float(np.min(d)),
                      "kbit_per_s": size * 8 / 1000 / (len(rows) / float(info.fps)),
                      "description": QUALITIES[q].description}
    print(json.dumps(summary, indent=1))
    Path(args.output).write_text(json.dumps({"summary": summary, "frames": rows}, indent=1))
    print(f"wrote {args.output} (work files in {tmp})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
