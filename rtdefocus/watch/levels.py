"""The band-pass level the watcher judges focus against, read while the model was right.

A look's band ratio (:attr:`~rtdefocus.watch.residual.ResidualReport.band_ratio`, with the
light fit's gain taken out) moves a few per cent with the content's spectrum and the camera's
noise: on a 240x180 frame a cut between two photographs moves it 1.0-1.5 %, about as much as
every blur radius grown by 15 %. The level is therefore kept per kind of content, keyed by the
prediction's own band-pass RMS (:attr:`~.residual.ResidualReport.band_rms`: how much fine
content the look had, which also sets how much the camera's noise adds), and a look is judged
against the looks of like content only.

MEASURED (`python tools/bench_watch.py --table levels --size 240x180 webcam_cubicle cubicle`,
the drift clip on the unchanged set-ups): within a picture's still, pan or zoom the band RMS
spreads by a factor up to 1.067, whose 1.5-fold (in log) is the watcher's ``band_match`` of
1.10; the clip's two pictures lie a factor 2.0 (cubicle) and 2.7 (webcam) apart, their levels
1.0-1.5 % apart. Two minutes of that clip (`rtdefocus.study.eval_drift.run_false_alarm`,
240x180, looks every 0.25 s) put no look judged against like content further than 0.41 %
(cubicle) and 0.48 % (webcam) from its level: the watcher's focus threshold of 1.2 % is 2.5x
that. Every blur radius grown by 15 % moves the level 3 % (240x180, the photographs) to 6 %
(400x300), 1.2-1.7 % on the smooth textures of ``tests/test_watcher.py`` at 240x180.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from .predictor import ResidualReport

__all__ = ["BandLevels", "band_level", "content_informs"]


def band_level(r: ResidualReport) -> float:
    """The band ratio with the light fit's gain taken out: a light mend moves the gain into
    the albedo, which would otherwise move the ratio's level as much."""
    return r.band_ratio / r.gain if r.gain > 0 else float("nan")


def content_informs(shown: np.ndarray, lut: np.ndarray, min_contrast: float,
                    min_band: float) -> dict:
    """Per kind of change, whether a shown 8-bit frame has the content to judge it: light
    wants contrast (the grey's standard deviation over ``min_contrast``), focus fine detail
    (its band-pass RMS over ``min_band``); any frame can show geometry."""
    # decode_lut's grey by table and one weighted sum (a tenth of its time per look)
    table = np.ascontiguousarray(np.asarray(lut, np.float32).T[None])
    lin = cv2.transform(cv2.LUT(np.ascontiguousarray(shown, np.uint8), table),
                        np.full((1, 3), 1.0 / 3.0, np.float32))
    band = cv2.GaussianBlur(lin, (0, 0), 1.0) - cv2.GaussianBlur(lin, (0, 0), 2.0)
    return {"geometry": True, "light": float(lin.std()) > min_contrast,
            "focus": float(np.sqrt(np.mean(band ** 2))) > min_band}


class BandLevels:
    """Band levels of looks at a right model, each with its content's band-pass RMS.

    Parameters
    ----------
    match : looks whose band-pass RMS is within this factor of each other have like content.
    looks : looks of like content that make a level.
    keep : the latest looks kept.
    """

    def __init__(self, match: float, looks: int, keep: int = 48):
        self.match, self.looks, self.keep = float(match), int(looks), int(keep)
        self.entries: list[tuple[float, float]] = []

    def __len__(self) -> int:
        return len(self.entries)

    def clear(self) -> None:
        """Forget every level (the kernels changed: the levels belong to the old ones)."""
        self.entries = []

    def add(self, r: ResidualReport) -> None:
        """Keep the level of a look at a right model."""
        level = band_level(r)
        if math.isfinite(level):
            self.entries = (self.entries + [(r.band_rms, level)])[-self.keep:]

    def like(self, rms: float, r: ResidualReport) -> bool:
        """Whether a look of band-pass RMS ``rms`` had content like ``r``'s (any, when a report
        does not say its band-pass RMS)."""
        e = r.band_rms
        if not (math.isfinite(e) and e > 0 and math.isfinite(rms) and rms > 0):
            return True
        return abs(math.log(rms / e)) <= math.log(self.match)

    def known(self) -> bool:
        """Whether any content's level is known."""
        return len(self.entries) >= self.looks

    def level(self, r: ResidualReport) -> float | None:
        """The median level of the looks of content like ``r``'s, or None before ``looks``
        of them."""
        like = [b for e, b in self.entries if self.like(e, r)]
        return float(np.median(like)) if len(like) >= self.looks else None

    def measure_again(self, reports: list[ResidualReport]) -> None:
        """The levels of content like ``reports[-1]``'s replaced by these reports' (a right
        model's, as a retracted focus change showed)."""
        self.entries = [(e, b) for e, b in self.entries if not self.like(e, reports[-1])]
        for r in reports:
            self.add(r)
