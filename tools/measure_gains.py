#!/usr/bin/env python
"""Measure the compensation gains the quality tests guard, in the tests' own settings, so that
their thresholds can be set from measurement with a stated margin.

Sections (``--sections``, comma-separated):

``compensate``  tests/test_compensate.py: presets cubicle/tilted/pillar at 400x300 (camera
                640x480, seed 3), the four photographs; PSNR/SSIM gain of ``ycbcr`` over geometry
                only over the display rect and in the 16-px band either side of the fold.
``eval``        ``rtdefocus eval --quick`` (as tests/test_eval.py runs it): gains per row.
``demo``        the demo at 400x300 (as tests/test_demo.py runs it): the chelsea row.

Example::

    .venv/bin/python tools/measure_gains.py --sections compensate,eval,demo

Prints one line per measurement; the tests quote these numbers next to their thresholds.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def section_compensate() -> None:
    import test_compensate as tc

    images = tc.photographs()
    for preset in tc.PRESETS:
        for name in tc.PHOTOS:
            v = tc.camera_views(preset, name, images[name])
            row = []
            for region in ("mask", "band"):
                m = v[region]
                dp = tc.psnr(v["ycbcr"], v["sharp"], m) - tc.psnr(v["none"], v["sharp"], m)
                ds = tc.ssim(v["ycbcr"], v["sharp"], m) - tc.ssim(v["none"], v["sharp"], m)
                row.append(f"{region}: {dp:+.2f} dB  SSIM {ds:+.4f}")
            print(f"compensate {preset:8s} {name:10s} " + "   ".join(row), flush=True)


def section_eval() -> None:
    from rtdefocus import cli

    with tempfile.TemporaryDirectory() as out:
        cli.main(["-q", "eval", "--quick", "-o", out, "--methods", "ycbcr,wiener",
                  "--layouts", "default,cross_fold", "--numpy-iterations", "1"])
        result = json.loads((Path(out) / "eval.json").read_text())
    for r in result["presets"]["cubicle"]["rows"]:
        print(f"eval {r['name']:8s} PSNR gain {r['psnr']['ycbcr/default'] - r['psnr']['none']:+.2f}"
              f" dB  SSIM gain {r['ssim']['ycbcr/default'] - r['ssim']['none']:+.4f}")
    print("eval gains", json.dumps(result["presets"]["cubicle"]["gains"]))


def section_demo() -> None:
    from rtdefocus.study.demo import run_demo
    from rtdefocus.study.samples import demo_images

    images = demo_images()
    with tempfile.TemporaryDirectory() as out:
        result = run_demo(out, images={k: images[k] for k in ("chelsea", "text")},
                          methods=("ycbcr", "wiener"), projector_size=(400, 300),
                          camera_size=(640, 480))
    for r in result["rows"]:
        print(f"demo {r['name']:16s} PSNR gain {r['psnr']['ycbcr'] - r['psnr']['none']:+.2f} dB"
              f"  SSIM gain {r['ssim']['ycbcr'] - r['ssim']['none']:+.4f}  edges "
              f"{r['edges_output']}")


SECTIONS = {"compensate": section_compensate, "eval": section_eval, "demo": section_demo}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sections", default="compensate,eval,demo")
    args = p.parse_args(argv)
    for name in args.sections.split(","):
        t0 = time.perf_counter()
        SECTIONS[name]()
        print(f"[{name}: {time.perf_counter() - t0:.0f} s]", flush=True)
    return 0


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    raise SystemExit(main())
