"""``rtdefocus aim``: the pictures that help point the camera and focus the projector.

Pure functions of camera frames (no window, no camera), so that they are tested on the
virtual set-up; :mod:`rtdefocus.hardware.aim_loop` drives them with a camera and two windows.

* :func:`aim_pattern`: what the projector holds: white, a grid or a checker.
* :func:`find_projected_area`: the projected area in the camera picture (outline, mask).
* :func:`clipped_mask`: camera pixels at the top of their range (the exposure is too long).
* :func:`wall_regions`: one region per wall: the calibration's planes where one is known,
  else the left and right halves of the projected area (a corner's two walls, roughly).
* :func:`focus_reading`: the edge blur of the checker in one region. A step edge blurred by a
  Gaussian of σ px has a peak slope of contrast / (σ √(2π)), so σ = contrast / (√(2π) · slope),
  read at the checker's edges (the strongest slopes relative to the local contrast). σ in
  projector pixels is what the audience gets before compensation: turn the focus ring until
  the walls' values are low and about equal.
* :func:`compose_aim_frame`: the laptop's preview: the camera picture, the area outlined,
  clipped pixels in red, a focus meter per wall, the pattern's name and the keys.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError

#: The patterns the projector can hold, with the key that selects each.
PATTERN_KEYS = {"w": "white", "g": "grid", "c": "checker"}
PATTERNS = tuple(PATTERN_KEYS.values())

_SQRT_2PI = float(np.sqrt(2.0 * np.pi))


def pattern_cell(projector_size: tuple[int, int]) -> int:
    """Checker cell / grid spacing in projector pixels: 24 cells across, at least 8 px."""
    return max(8, int(projector_size[0]) // 24)


def aim_pattern(kind: str, projector_size: tuple[int, int]) -> np.ndarray:
    """``"white"``, ``"grid"`` (2-px white lines on black) or ``"checker"``, (Hp, Wp, 3) uint8."""
    w, h = (int(v) for v in projector_size)
    if kind == "white":
        return np.full((h, w, 3), 255, np.uint8)
    cell = pattern_cell(projector_size)
    ys, xs = np.mgrid[0:h, 0:w]
    if kind == "grid":
        on = ((xs % cell) < 2) | ((ys % cell) < 2) | (xs >= w - 2) | (ys >= h - 2)
    elif kind == "checker":
        on = ((xs // cell) + (ys // cell)) % 2 == 0
    else:
        raise InputError(f"aim pattern must be one of {', '.join(PATTERNS)}; got {kind!r}")
    return np.repeat((on * 255).astype(np.uint8)[:, :, None], 3, axis=2)


def _luma(img: np.ndarray) -> np.ndarray:
    """Luma (OpenCV's weighted grey, uint8) of an RGB frame; a single-channel one as it is."""
    img = np.asarray(img)
    return cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img


@dataclass
class ProjectedArea:
    """Where the projector lights the camera picture.

    Attributes
    ----------
    mask : (Hc, Wc) bool
    outline : (N, 2) int32 camera pixels, the area's outer contour (simplified).
    fraction : float, share of the camera picture it covers.
    """

    mask: np.ndarray
    outline: np.ndarray
    fraction: float

    def projector_px_per_camera_px(self, projector_size: tuple[int, int]) -> float:
        """Projector pixels per camera pixel (linear), from the areas."""
        lit = max(int(self.mask.sum()), 1)
        return float(np.sqrt(projector_size[0] * projector_size[1] / lit))


def find_projected_area(lit: np.ndarray, dark: np.ndarray | None = None) -> ProjectedArea | None:
    """The projected area from a camera frame of a white screen (``lit``), less one of a black
    screen (``dark``) where there is one: Otsu's threshold, the largest component, holes
    filled. None when nothing stands out (the camera does not see the projection)."""
    g = _luma(lit).astype(np.int16)
    if dark is not None:
        g = g - _luma(dark).astype(np.int16)
    g = np.clip(g, 0, 255).astype(np.uint8)
    g = cv2.GaussianBlur(g, (5, 5), 0)
    if int(g.max()) - int(g.min()) < 20:
        return None
    _, binary = cv2.threshold(g, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    n, labels, stats, _ = cv2.connectedComponentsWithStats(binary, connectivity=8)
    if n < 2:
        return None
    biggest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    comp = (labels == biggest).astype(np.uint8)
    contours, _ = cv2.findContours(comp, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    contour = max(contours, key=cv2.contourArea)
    mask = np.zeros_like(comp)
    cv2.drawContours(mask, [contour], -1, 1, thickness=cv2.FILLED)
    eps = 0.004 * cv2.arcLength(contour, True)
    outline = cv2.approxPolyDP(contour, eps, True).reshape(-1, 2).astype(np.int32)
    if mask.sum() < 0.002 * mask.size:
        return None
    return ProjectedArea(mask.astype(bool), outline, float(mask.mean()))


def clipped_mask(frame: np.ndarray, level: int = 250) -> np.ndarray:
    """(Hc, Wc) bool: pixels with any channel at ``level`` or above (clipped white)."""
    frame = np.asarray(frame)
    return (frame >= level).any(axis=2) if frame.ndim == 3 else frame >= level


@dataclass
class Region:
    """One wall's part of the camera picture."""

    name: str
    mask: np.ndarray


def wall_regions(area: ProjectedArea, calib=None) -> list[Region]:
    """One region per wall inside ``area``: the planes of ``calib`` in camera pixels
    (``calib.layout_cam``), else the area's left and right halves."""
    mask = area.mask
    h, w = mask.shape
    if calib is not None and tuple(calib.camera_size) == (w, h):
        ys, xs = np.mgrid[0:h, 0:w]
        label = np.asarray(calib.layout_cam.label(xs.astype(np.float64), ys.astype(np.float64)))
        names = ["left wall", "right wall"] if calib.n_planes == 2 else \
            [f"plane {i + 1}" for i in range(calib.n_planes)]
        out = [Region(names[i], mask & (label == i)) for i in range(calib.n_planes)]
        return [r for r in out if r.mask.any()]
    xs = np.nonzero(mask.any(axis=0))[0]
    if xs.size == 0:
        return []
    mid = (int(xs[0]) + int(xs[-1]) + 1) // 2
    left, right = mask.copy(), mask.copy()
    left[:, mid:] = False
    right[:, :mid] = False
    return [Region("left", left), Region("right", right)]


@dataclass
class FocusReading:
    """The focus meter of one region.

    Attributes
    ----------
    blur_camera_px : float or None
        Edge blur σ in camera pixels (None: no edges to read, e.g. a white pattern).
    blur_projector_px : float or None
        The same in projector pixels (what the audience sees before compensation).
    edges : int
        Camera pixels the reading is taken from.
    """

    blur_camera_px: float | None
    blur_projector_px: float | None
    edges: int


def focus_reading(frame: np.ndarray, region: np.ndarray, *, cell_camera_px: float,
                  projector_per_camera: float = 1.0, min_edges: int = 30) -> FocusReading:
    """Edge blur σ of a checker (or grid) seen by the camera inside ``region`` (module
    docstring). ``cell_camera_px`` is the pattern's cell in camera pixels (sets the window of
    the local contrast); ``projector_per_camera`` converts σ to projector pixels."""
    return focus_readings(frame, [region], cell_camera_px=cell_camera_px,
                          projector_per_camera=projector_per_camera, min_edges=min_edges)[0]


def focus_readings(frame: np.ndarray, regions: list[np.ndarray], *, cell_camera_px: float,
                   projector_per_camera: float = 1.0, min_edges: int = 30) -> list[FocusReading]:
    """:func:`focus_reading` for several regions of one frame (the edge fields computed once)."""
    g = _luma(frame).astype(np.float32)
    half = max(2, int(round(cell_camera_px)))
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (2 * half + 1, 2 * half + 1))
    contrast = cv2.dilate(g, kernel) - cv2.erode(g, kernel)
    gx = cv2.Sobel(g, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(g, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    slope = cv2.magnitude(gx, gy)
    out = []
    for region in regions:
        # Inside the region, away from its border (the lit area's own edge is not the pattern's).
        inner = cv2.erode(region.astype(np.uint8), kernel).astype(bool)
        top = float(np.percentile(contrast[inner], 90)) if inner.any() else 0.0
        use = inner & (contrast > 0.5 * top) & (top > 10.0)
        n = int(use.sum())
        if n < min_edges:
            out.append(FocusReading(None, None, n))
            continue
        ratio = slope[use] / contrast[use]
        # The steepest slopes relative to their contrast sit on the edges' centres; the Sobel
        # operator's own 3-px smoothing is taken out in quadrature (σ_sobel² ≈ 1/3 px²).
        peak = float(np.percentile(ratio, 97))
        sigma = 1.0 / (_SQRT_2PI * max(peak, 1e-6))
        sigma = float(np.sqrt(max(sigma * sigma - 1.0 / 3.0, 0.0)))
        out.append(FocusReading(sigma, sigma * projector_per_camera, n))
    return out


# --------------------------------------------------------------------------- the preview
_GREEN, _RED, _WHITE, _YELLOW = (60, 220, 60), (255, 40, 40), (255, 255, 255), (255, 210, 0)


def _text(img, text, org, scale=0.5, colour=_WHITE):
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, 1, cv2.LINE_AA)


def compose_aim_frame(frame: np.ndarray, *, area: ProjectedArea | None, clipped: np.ndarray,
                      regions: list[Region], readings: list[FocusReading], pattern: str,
                      size: tuple[int, int] | None = None) -> np.ndarray:
    """The preview: ``frame`` with the projected area outlined (green), clipped pixels in red,
    a focus meter per region (a bar, longer = sharper, and σ in projector pixels), and a
    banner with the pattern, the clipped share and the keys. Returns (H, W, 3) uint8 RGB,
    resized to ``size = (w, h)`` when given (aspect kept, letterboxed)."""
    out = np.array(frame, dtype=np.uint8, copy=True)
    if out.ndim == 2:
        out = cv2.cvtColor(out, cv2.COLOR_GRAY2RGB)
    h, w = out.shape[:2]
    out[clipped] = _RED
    if area is not None:
        cv2.polylines(out, [area.outline.reshape(-1, 1, 2)], True, _GREEN, max(1, w // 320),
                      cv2.LINE_8)
    share = float(clipped[area.mask].mean()) if area is not None and area.mask.any() else \
        float(clipped.mean())
    for region, reading in zip(regions, readings, strict=True):
        ys, xs = np.nonzero(region.mask)
        if xs.size == 0:
            continue
        cx, cy = int(xs.mean()), int(ys.mean())
        bw, bh = max(40, w // 8), max(6, h // 60)
        x0, y0 = cx - bw // 2, cy
        cv2.rectangle(out, (x0, y0), (x0 + bw, y0 + bh), (40, 40, 40), cv2.FILLED)
        if reading.blur_projector_px is None:
            label = f"{region.name}: focus meter on the checker (c)" if pattern != "checker" \
                else f"{region.name}: no edges"
        else:
            # Longer = sharper: full at 0.5 projector px of blur, empty at 8.
            sharp = float(np.clip((8.0 - reading.blur_projector_px) / 7.5, 0.0, 1.0))
            cv2.rectangle(out, (x0, y0), (x0 + int(round(bw * sharp)), y0 + bh), _YELLOW,
                          cv2.FILLED)
            label = f"{region.name}: blur {reading.blur_projector_px:.1f} px"
        _text(out, label, (x0, max(12, y0 - 6)), scale=max(0.35, w / 1600))
    banner = (f"pattern {pattern} (w white, g grid, c checker)  clipped {share:.1%}  "
              + ("projection not found" if area is None else "") + "  q quit")
    _text(out, banner, (8, max(16, h // 30)), scale=max(0.35, w / 1600),
          colour=_RED if area is None or share > 0.005 else _WHITE)
    if size is not None and (w, h) != tuple(size):
        from ..imageio import fit_image

        out = fit_image(out, tuple(size))
    return out


@dataclass
class AimView:
    """What one camera frame tells: the area, clipped pixels, the regions and their focus."""

    area: ProjectedArea | None
    clipped: np.ndarray
    regions: list[Region]
    readings: list[FocusReading]


def analyse(frame: np.ndarray, area: ProjectedArea | None, *, pattern: str,
            projector_size: tuple[int, int], calib=None) -> AimView:
    """Clipped pixels, the wall regions and, on the checker, their focus."""
    clipped = clipped_mask(frame)
    if area is None:
        return AimView(None, clipped, [], [])
    regions = wall_regions(area, calib)
    ratio = area.projector_px_per_camera_px(projector_size)
    cell = pattern_cell(projector_size) / ratio
    if pattern == "checker":
        readings = focus_readings(frame, [r.mask for r in regions], cell_camera_px=cell,
                                  projector_per_camera=ratio)
    else:
        readings = [FocusReading(None, None, 0) for _ in regions]
    return AimView(area, clipped, regions, readings)
