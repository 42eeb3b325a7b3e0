"""A picture of what calibration learnt about the camera and the light: the camera's
and the projector's response curves, the lens's distortion grid, and the PSF dots that were
skipped and why (:func:`camera_diagnostics`). OpenCV drawing only, like the other pictures of
the calibration report, so it needs no optional extra."""

from __future__ import annotations

import cv2
import numpy as np

from ..planar import distortion_scale
from .file import Calibration
from .geometry.lens import lens_k, observed_points

__all__ = ["camera_diagnostics", "response_panel", "distortion_panel", "skipped_panel"]

_RGB = [(230, 60, 60), (60, 200, 60), (70, 110, 255)]
_H = 300         # panel height (px)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def _text(img: np.ndarray, s: str, xy: tuple[int, int], scale: float = 0.45,
          colour=(255, 255, 255)) -> None:
    cv2.putText(img, s, xy, _FONT, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, s, xy, _FONT, scale, colour, 1, cv2.LINE_AA)


def _plot(lut: np.ndarray | None, title: str, note: str, size: int = _H) -> np.ndarray:
    """One response plot: code (0..255, x) -> linear light (0..1, y) per channel, with the
    identity dashed for reference."""
    img = np.full((size, size, 3), 24, np.uint8)
    m0, m1 = 34, 14                   # margins: bottom/left for labels, top/right
    w = size - m0 - m1

    def P(x, y):
        return np.stack([m0 + x * w, size - m0 - y * w], axis=-1)

    cv2.rectangle(img, (m0, m1), (m0 + w, m1 + w), (90, 90, 90), 1)
    for t in np.linspace(0, 1, 20, endpoint=False)[::2]:        # the identity, dashed
        a, b = P(np.array([t, t + 0.05]), np.array([t, t + 0.05]))
        cv2.line(img, tuple(int(v) for v in a), tuple(int(v) for v in b), (110, 110, 110), 1)
    if lut is None:
        _text(img, "not measured", (m0 + 10, size // 2))
    else:
        lut = np.atleast_2d(np.asarray(lut, np.float64))
        x = np.arange(lut.shape[1]) / (lut.shape[1] - 1)
        for c in range(lut.shape[0]):
            pts = np.round(P(x, np.clip(lut[c], 0, 1)) * 16).astype(np.int32)
            cv2.polylines(img, [pts], False, _RGB[c % 3], 1, cv2.LINE_AA, shift=4)
    _text(img, title, (m0, m1 + 16))
    _text(img, note, (m0, m1 + 34), 0.4, (200, 200, 200))
    _text(img, "code 0..255", (m0 + w // 2 - 40, size - 10), 0.4)
    _text(img, "0", (m0 - 14, size - m0 + 4), 0.4)
    _text(img, "1", (m0 - 14, m1 + 6), 0.4)
    return img


def response_panel(calib: Calibration) -> np.ndarray:
    """Two plots side by side: the camera's inverse response (code -> linear, per channel) and
    the projector's response (code -> linear light)."""
    r = calib.meta.get("radiometry", {})
    kind = r.get("camera_response", "linear (format 1)" if calib.camera_lut is None else "")
    gammas = r.get("gamma")
    g = "gamma " + "/".join(f"{v:.2f}" for v in gammas) if gammas else ""
    cam = _plot(calib.camera_lut if calib.camera_lut is not None else np.arange(256) / 255.0,
                "camera: code -> linear", str(kind))
    proj = _plot(calib.response_lut, "projector: code -> light", g)
    return np.concatenate([cam, np.full((_H, 4, 3), 255, np.uint8), proj], axis=1)


def distortion_panel(calib: Calibration, lines: int = 9, exaggerate: float | None = None
                     ) -> np.ndarray:
    """The camera frame with a grid of lines straight in ideal pixels (grey) drawn where the
    camera sees them (cyan): how the lens bends a straight edge. The bend is magnified so
    that the corner displacement shows as about 4 % of the frame (the factor is printed)."""
    wc, hc = calib.camera_size
    scale = _H / hc
    out_w = max(int(round(wc * scale)), 1)
    img = np.full((_H, out_w, 3), 24, np.uint8)
    k = lens_k(calib)
    corner = 0.0 if k is None else abs(k[0] + k[1]) * distortion_scale((wc, hc))[2]
    if exaggerate is None:
        exaggerate = 1.0 if corner <= 0 else max(1.0, 0.04 * np.hypot(wc, hc) / corner)
    t = np.linspace(0.0, 1.0, 200)
    for frac in np.linspace(0.0, 1.0, lines):
        for seg in (np.stack([t * (wc - 1), np.full_like(t, frac * (hc - 1))], axis=1),
                    np.stack([np.full_like(t, frac * (wc - 1)), t * (hc - 1)], axis=1)):
            obs = seg + exaggerate * (observed_points(calib, seg) - seg)
            for pts, col in ((seg, (80, 80, 80)), (obs, (0, 220, 255))):
                p = np.round(pts * scale * 16).astype(np.int32)
                cv2.polylines(img, [p], False, col, 1, cv2.LINE_AA, shift=4)
    d = calib.meta.get("geometry", {}).get("distortion", {})
    if k is None:
        note = "ideal lens (k1 = 0)" if calib.camera_distortion is not None else "lens not modelled"
        if d.get("k1") is not None:
            note += f"; measured k1 {d['k1']:+.4f} left out ({d.get('corner_px', 0):.2f} px)"
    else:
        note = (f"k1 {k[0]:+.4f}  k2 {k[1]:+.4f}: {corner:.1f} px at the corners "
                f"(drawn x{exaggerate:.0f})")
    _text(img, "lens distortion", (8, 18))
    _text(img, note, (8, 36), 0.4, (200, 200, 200))
    if d.get("rms_px_without") is not None:
        _text(img, f"crossings off a homography: {d['rms_px_without']} px -> {d.get('rms_px')} px",
              (8, _H - 10), 0.4, (200, 200, 200))
    return img


def skipped_panel(calib: Calibration) -> np.ndarray:
    """The projector frame with every PSF dot (green: measured, red cross: skipped and filled
    from its neighbours) and why each was skipped."""
    wp, hp = calib.projector_size
    scale = _H / hp
    img = np.full((_H, max(int(round(wp * scale)), 1), 3), 24, np.uint8)
    p = calib.meta.get("psf", {})
    skipped = [tuple(v) for v in p.get("skipped", [])]
    why = p.get("skipped_why", [""] * len(skipped))
    if calib.psf_points_proj is None:
        _text(img, "PSF dots: not measured", (8, 18))
        return img
    for x, y in calib.psf_points_proj:
        cv2.circle(img, (int(round(x * scale)), int(round(y * scale))), 2, (60, 200, 60), -1)
    for (x, y) in skipped:
        c = np.array([x * scale, y * scale])
        for d in ((5, 5), (5, -5)):
            a, b = np.round(c - d).astype(int), np.round(c + d).astype(int)
            cv2.line(img, tuple(int(v) for v in a), tuple(int(v) for v in b), (255, 50, 50), 2)
    _text(img, f"PSF dots: {len(calib.psf_points_proj)} measured, {len(skipped)} skipped", (8, 18))
    reasons: dict[str, int] = {}
    for w in why:
        reasons[w or "too faint"] = reasons.get(w or "too faint", 0) + 1
    for i, (w, n) in enumerate(sorted(reasons.items(), key=lambda kv: -kv[1])[:4]):
        _text(img, f"{n} x {w}", (8, 36 + 16 * i), 0.4, (255, 140, 140))
    if skipped:
        _text(img, "filled from neighbours on their plane", (8, _H - 10), 0.4, (200, 200, 200))
    return img


def camera_diagnostics(calib: Calibration) -> np.ndarray:
    """(300, W, 3) uint8 RGB: response curves, distortion grid and skipped dots side by side
    (the calibration report's ``*_camera.png``)."""
    panels = [response_panel(calib), distortion_panel(calib), skipped_panel(calib)]
    sep = np.full((_H, 4, 3), 255, np.uint8)
    out = []
    for p in panels:
        out += [p, sep]
    return np.concatenate(out[:-1], axis=1)
