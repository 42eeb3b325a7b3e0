"""The demo's rooms section: a set-up of more than two planes, calibrated through ``capture``
only like the main story (``rtdefocus demo --rooms corner_ceiling``; on by default with
``corner_ceiling``, two walls and the ceiling whose three folds meet inside the picture).

Per preset: the calibration file, its geometry picture (each plane tinted, every fold drawn)
and kernel picture, and per photograph the side-by-side (input | projected, no correction |
geometry only | geometry + defocus | sharp reference, zooms on a fold) with the table's rows.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from .. import sim
from ..calib import calibrate
from ..calib.geometry.diagnostics import geometry_diagnostics
from ..calib.psf import psf_diagnostics
from ..compensate import Compensator
from ..imageio import write_image
from .scores import ImageScores, score_image

__all__ = ["run_rooms"]


def run_rooms(out: Path, presets: tuple[str, ...], images: dict[str, np.ndarray], *,
              methods: tuple[str, ...] = ("ycbcr",), seed: int = 0, progress=None,
              step: Callable[[str], None] | None = None, side_by_side=None,
              **procam_options) -> tuple[list[Path], dict[str, list[ImageScores]], dict]:
    """Calibrate each preset through ``capture`` and score ``images`` on it.

    Returns (files written, preset -> rows of :class:`ImageScores`, preset -> calibration
    summary: planes, folds, captures, seconds). ``side_by_side(calib, rect, views, image)``
    draws the per-image picture (the demo's own).
    """
    say = step or (lambda msg: None)
    files: list[Path] = []
    rows: dict[str, list[ImageScores]] = {}
    summary: dict = {}
    for preset in presets:
        say(f"room {preset!r}: calibrating through capture() only")
        procam = sim.VirtualProCam(preset, seed=seed, **procam_options)
        calib = calibrate(procam, progress=progress)
        files.append(calib.save(out / f"setup_{preset}.npz"))
        files.append(write_image(out / f"{preset}_calibration_geometry.png",
                                 geometry_diagnostics(calib)))
        files.append(write_image(out / f"{preset}_calibration_kernels.png",
                                 psf_diagnostics(calib, truth_radius=procam.truth.radius_map)))
        geo = calib.meta.get("geometry", {})
        summary[preset] = {"planes": calib.n_planes, "planes_true": procam.truth.n_planes,
                           "folds": int(calib.folds_proj.shape[0]),
                           "captures": int(sum(calib.meta.get("captures", {}).values())),
                           "seconds": calib.meta.get("seconds"),
                           "fold_disagreement_px": geo.get("fold_disagreement_px")}
        comps = {m: Compensator(calib, method=m) for m in methods}
        rows[preset] = []
        for name, image in images.items():
            say(f"room {preset!r}: {name}")
            scores, shown = score_image(procam, calib, comps, name, image)
            rows[preset].append(scores)
            if side_by_side is not None:
                rect = calib.display_rect(image.shape[1::-1])
                files.append(write_image(out / f"{preset}_{name}_side_by_side.png",
                                         side_by_side(calib, rect, shown, image)))
    return files, rows, summary
