"""Figures of ``surface="flatten"`` against ``"keep"`` on the simulator (issue 12).

    python tools/flatten_eval.py [--size 240x180] [--backend numpy] [--preset fabric]

Prints, with the oracle calibration (true albedo, ambient, kernels):
* the spatial coefficient of variation of a flat grey field in the camera view (display
  rectangle, 5 % inset), keep vs flatten;
* per photograph, PSNR after one global gain and offset of the camera view against the input
  on a uniform white wall (the input resized into the display rectangle), keep vs flatten;
* the defocus gain in the fold band (PSNR of geometry + defocus minus geometry only, each
  against its own sharp display), flatten vs keep.
"""

from __future__ import annotations

import argparse
import json

import cv2
import numpy as np

import rtdefocus as rd
from rtdefocus.samples import photographs
from rtdefocus.scores import (
    camera_view,
    coefficient_of_variation,
    near_folds_mask,
    psnr,
    psnr_affine,
    rect_mask,
)


def inset_mask(rect, shape, frac=0.05):
    x, y, w, h = rect
    dx, dy = int(frac * w), int(frac * h)
    return rect_mask((x + dx, y + dy, w - 2 * dx, h - 2 * dy), shape)


def on_white_wall(image, rect, shape):
    """The input as on a uniform white wall: resized into the display rectangle, linear."""
    x, y, w, h = rect
    out = np.zeros(shape + (3,), np.uint8)
    out[y:y + h, x:x + w] = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
    return out


def evaluate(procam, calib, images: dict, backend="numpy", iterations=None) -> dict:
    comps = {(s, m): rd.Compensator(calib, backend=backend, surface=s, method=m,
                                    iterations=iterations)
             for s in ("keep", "flatten") for m in ("none", "ycbcr")}
    wc, hc = calib.camera_size
    res = {"cov": {}, "psnr_affine": {}, "fold_gain": {}, "clipped": {}}
    grey = np.full((90, 120, 3), 128, np.uint8)
    mask = inset_mask(calib.display_rect((120, 90)), (hc, wc))
    for s in ("keep", "flatten"):
        view = camera_view(procam, calib, comps[(s, "ycbcr")].compensate(grey))
        res["cov"][s] = coefficient_of_variation(view, mask)
    for name, img in images.items():
        h, w = img.shape[:2]
        rect = calib.display_rect((w, h))
        m = inset_mask(rect, (hc, wc))
        band = m & near_folds_mask(calib, (hc, wc), 12.0)
        white = on_white_wall(img, rect, (hc, wc))
        for s in ("keep", "flatten"):
            geo = comps[(s, "none")].compensate(img)
            ours = comps[(s, "ycbcr")].compensate(img, warm_start=False)
            res["clipped"][f"{name}/{s}"] = comps[(s, "ycbcr")].last_info.get("clipped")
            view = camera_view(procam, calib, ours)
            sharp = camera_view(procam, calib, geo, sharp=True)
            res["psnr_affine"][f"{name}/{s}"] = psnr_affine(view, white, m)
            res["fold_gain"][f"{name}/{s}"] = (psnr(view, sharp, band)
                                               - psnr(camera_view(procam, calib, geo), sharp, band))
    return res


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="240x180")
    ap.add_argument("--preset", default="fabric")
    ap.add_argument("--backend", default="numpy")
    ap.add_argument("--images", default="chelsea,coffee,astronaut")
    args = ap.parse_args()
    wp, hp = (int(v) for v in args.size.split("x"))
    procam = rd.sim.VirtualProCam(args.preset, projector_size=(wp, hp),
                                  camera_size=(wp * 4 // 3, hp * 4 // 3))
    calib = rd.sim.oracle_calibration(procam)
    photos = photographs()
    images = {n: photos[n] for n in args.images.split(",")}
    res = evaluate(procam, calib, images, backend=args.backend)
    print(json.dumps(res, indent=1))
    k = res["psnr_affine"]
    print("cov keep/flatten = %.2f" % (res["cov"]["keep"] / res["cov"]["flatten"]))
    for n in images:
        f = res["fold_gain"]
        print(f"{n}: psnr_affine flatten - keep = {k[n + '/flatten'] - k[n + '/keep']:+.2f} dB; "
              f"fold gain flatten/keep = {f[n + '/flatten'] / f[n + '/keep']:.2f}")


if __name__ == "__main__":
    main()
