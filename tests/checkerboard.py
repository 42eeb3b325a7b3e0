"""A checkerboard input and where a display rect says its inner corners belong in the camera
(shared by the warp and geometry tests)."""

from __future__ import annotations

import cv2
import numpy as np

SQ, NX, NY = 40, 10, 7            # 10 x 7 squares of 40 px -> 9 x 6 inner corners
QUIET = SQ // 2                   # a white quiet zone, as the detector needs


def board() -> np.ndarray:
    """(H, W, 3) uint8 checkerboard with a quiet zone."""
    yy, xx = np.mgrid[0:NY * SQ, 0:NX * SQ]
    b = np.where((xx // SQ + yy // SQ) % 2 == 0, 230, 25).astype(np.uint8)
    b = np.pad(b, QUIET, constant_values=230)
    return np.repeat(b[..., None], 3, axis=2)


def corner_errors(camera_rgb: np.ndarray, rect, board_shape) -> tuple[np.ndarray, np.ndarray]:
    """Detected inner corners (sub-pixel) vs where ``rect`` places them.

    Returns (errors (n,) camera px, detected corners (NY-1, NX-1, 2) in board order).
    Inner corner (i, j) is the input point u = QUIET + i*SQ - 0.5 (between two pixels), which
    the rect places at x0 - 0.5 + (u + 0.5) * w / W.
    """
    cam = cv2.cvtColor(camera_rgb, cv2.COLOR_RGB2GRAY)
    found, corners = cv2.findChessboardCorners(cam, (NX - 1, NY - 1))
    assert found, f"checkerboard not found in the camera image (rect {rect})"
    corners = cv2.cornerSubPix(cam, corners, (7, 7), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
                               ).reshape(-1, 2)
    H, W = board_shape[:2]
    x0, y0, w, h = rect
    i, j = np.meshgrid(np.arange(1, NX), np.arange(1, NY))
    expect = np.stack([x0 - 0.5 + (QUIET + i.ravel() * SQ) * w / W,
                       y0 - 0.5 + (QUIET + j.ravel() * SQ) * h / H], axis=1)
    d = np.linalg.norm(expect[:, None] - corners[None], axis=2)
    assert len(set(d.argmin(axis=1))) == len(expect), "corners matched ambiguously"
    ordered = corners[d.argmin(axis=1)].reshape(NY - 1, NX - 1, 2)
    return d.min(axis=1), ordered


def through_warp(procam, calib, lens=None) -> tuple[np.ndarray, np.ndarray]:
    """The board warped with ``calib`` into the display rect (5 % margin), shown on
    ``procam`` and seen sharp: :func:`corner_errors` of that view.

    The view is divided by the view of a white frame, so a printed or woven wall's own edges do
    not pull the corner finder (the geometry is what is measured), and undistorted with
    ``lens`` (k1, k2) when given (the simulator's true lens, to judge a calibration that took
    its lens out)."""
    from rtdefocus.gl.warp import warp_image

    img = board()
    rect = calib.display_rect((img.shape[1], img.shape[0]), margin=0.05)
    frame = warp_image(calib, img, rect=rect)
    view = procam.capture(frame, sharp=True).astype(np.float32)
    white = procam.capture(np.full_like(frame, 255), sharp=True).astype(np.float32)
    view = np.clip(255.0 * view / np.maximum(white, 1.0), 0, 255).astype(np.uint8)
    if lens is not None:
        from rtdefocus.calib.geometry.lens import undistort_image

        view = undistort_image(view, lens, tuple(procam.camera_size))
    return corner_errors(view, rect, img.shape)
