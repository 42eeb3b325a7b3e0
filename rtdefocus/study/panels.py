"""Picture layout helpers of the demo pages (labelled panels side by side)."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["crop_box", "fit_height", "hstack", "label", "pad_to_width"]


def crop_box(calib, pad: int = 12) -> tuple[slice, slice]:
    """Camera rows/cols around the lit area (so the pictures show the projection, not the room)."""
    poly = np.asarray(calib.lit_polygon_cam)
    wc, hc = calib.camera_size
    x0, y0 = np.floor(poly.min(axis=0)).astype(int) - pad
    x1, y1 = np.ceil(poly.max(axis=0)).astype(int) + pad
    return slice(max(0, y0), min(hc, y1)), slice(max(0, x0), min(wc, x1))


def label(img: np.ndarray, text: str) -> np.ndarray:
    bar = np.full((28, img.shape[1], 3), 255, np.uint8)
    cv2.putText(bar, text, (6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([bar, img])


def fit_height(img: np.ndarray, h: int) -> np.ndarray:
    w = max(1, round(img.shape[1] * h / img.shape[0]))
    return cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA if img.shape[0] > h
                      else cv2.INTER_LINEAR)


def hstack(panels: list[np.ndarray], gap: int = 6) -> np.ndarray:
    h = max(p.shape[0] for p in panels)
    out = []
    for i, p in enumerate(panels):
        if p.shape[0] < h:
            p = np.vstack([p, np.full((h - p.shape[0], p.shape[1], 3), 255, np.uint8)])
        out.append(p)
        if i < len(panels) - 1:
            out.append(np.full((h, gap, 3), 255, np.uint8))
    return np.hstack(out)


def pad_to_width(img: np.ndarray, width: int) -> np.ndarray:
    if img.shape[1] >= width:
        return img
    return np.hstack([img, np.full((img.shape[0], width - img.shape[1], 3), 255, np.uint8)])
