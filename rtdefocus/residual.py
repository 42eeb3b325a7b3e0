"""A plane's smooth residual: where a wall is a plane only nearly (a bowed panel, a sagging
sheet), its camera <- projector map is the plane's homography plus a small smooth displacement.

The displacement of plane p is a uniform cubic B-spline over the projector frame with
``(gy, gx)`` control points of (dx, dy) camera px, ``ctrl[p]`` of shape (gy, gx, 2)::

    x_cam = H_cam_from_proj[p] · (x, y, 1)  (dehomogenised)  +  d_p(x, y)
    d_p(x, y) = sum_ij By_i(y) Bx_j(x) ctrl[p, i, j]

with the spans spread evenly over pixel centres 0 .. W-1 (and 0 .. H-1), clamped outside.
It is C² (no kink a checkerboard row would show), linear in ``ctrl`` (a least-squares fit), and
few numbers (a 9 × 7 grid: 126 per plane). This module is a leaf beside :mod:`rtdefocus.planar`.
"""

from __future__ import annotations

import numpy as np

from .errors import InputError
from .planar import apply_h

__all__ = ["DEFAULT_GRID", "basis", "displacement", "dense_displacement", "fit_residual",
           "check_residual", "proj_from_cam"]

#: Control points (gx, gy) of a plane's residual over the frame (>= 4 each).
DEFAULT_GRID = (9, 7)


def basis(coord: np.ndarray, n_px: int, n_ctrl: int) -> np.ndarray:
    """(N, n_ctrl) float64 cubic B-spline weights at ``coord`` (px, clamped to 0 .. n_px - 1):
    ``n_ctrl - 3`` uniform spans over the frame, each row summing to 1."""
    if n_ctrl < 4:
        raise InputError(f"a residual grid needs >= 4 control points per axis; got {n_ctrl}")
    spans = n_ctrl - 3
    u = np.clip(np.asarray(coord, np.float64).ravel(), 0.0, n_px - 1) / max(n_px - 1, 1) * spans
    i = np.minimum(np.floor(u), spans - 1).astype(np.intp)
    f = u - i
    w = np.stack([(1 - f) ** 3, 3 * f ** 3 - 6 * f ** 2 + 4, -3 * f ** 3 + 3 * f ** 2 + 3 * f + 1,
                  f ** 3], axis=1) / 6.0
    out = np.zeros((u.size, n_ctrl))
    rows = np.arange(u.size)[:, None]
    out[rows, i[:, None] + np.arange(4)] = w
    return out


def displacement(ctrl: np.ndarray, x: np.ndarray, y: np.ndarray,
                 projector_size: tuple[int, int]) -> np.ndarray:
    """(N, 2) camera px displacement of one plane's field ``ctrl`` (gy, gx, 2) at projector
    points (x, y) (each (N,))."""
    wp, hp = projector_size
    gy, gx = ctrl.shape[:2]
    bx, by = basis(x, wp, gx), basis(y, hp, gy)
    return np.einsum("ni,nj,ijc->nc", by, bx, np.asarray(ctrl, np.float64))


def dense_displacement(ctrl: np.ndarray, labels: np.ndarray,
                       projector_size: tuple[int, int]) -> np.ndarray:
    """(Hp, Wp, 2) float32: at each projector pixel centre, the displacement of the plane
    ``labels`` gives it (``ctrl`` (n, gy, gx, 2); labels (Hp, Wp) int)."""
    wp, hp = projector_size
    ctrl = np.asarray(ctrl, np.float64)
    n, gy, gx = ctrl.shape[:3]
    bx, by = basis(np.arange(wp), wp, gx), basis(np.arange(hp), hp, gy)
    out = np.zeros((hp, wp, 2))
    for p in range(n):
        sel = labels == p
        if not sel.any():
            continue
        field = np.einsum("yi,xj,ijc->yxc", by, bx, ctrl[p])
        out[sel] = field[sel]
    return out.astype(np.float32)


def fit_residual(pts_proj_xy: np.ndarray, resid_cam_xy: np.ndarray,
                 projector_size: tuple[int, int], grid: tuple[int, int] = DEFAULT_GRID,
                 smooth: float = 0.01) -> np.ndarray:
    """Least-squares control points (gy, gx, 2) of one plane's field through residuals.

    Parameters
    ----------
    pts_proj_xy : (N, 2) projector points of the plane's correspondences.
    resid_cam_xy : (N, 2) camera px: observed camera point minus the homography's.
    projector_size : (width, height).
    grid : (gx, gy) control points.
    smooth : weight of the second differences of the control points, relative to the mean
        data weight per control point: the field stays smooth where the data are sparse and
        falls to zero (its prior) where there are none.
    """
    wp, hp = projector_size
    gx, gy = (int(v) for v in grid)
    pts = np.asarray(pts_proj_xy, np.float64).reshape(-1, 2)
    r = np.asarray(resid_cam_xy, np.float64).reshape(-1, 2)
    bx, by = basis(pts[:, 0], wp, gx), basis(pts[:, 1], hp, gy)
    A = (by[:, :, None] * bx[:, None, :]).reshape(len(pts), gy * gx)
    AtA = A.T @ A
    # Second differences along x and y of the (gy, gx) grid, and a faint ridge to zero.
    idx = np.arange(gy * gx).reshape(gy, gx)
    rows = []
    for a, b, c in ((idx[:, :-2], idx[:, 1:-1], idx[:, 2:]), (idx[:-2], idx[1:-1], idx[2:])):
        for i, j, k in zip(a.ravel(), b.ravel(), c.ravel(), strict=True):
            row = np.zeros(gy * gx)
            row[[i, j, k]] = (1.0, -2.0, 1.0)
            rows.append(row)
    D = np.array(rows)
    scale = max(np.trace(AtA) / (gy * gx), 1e-9)
    M = AtA + smooth * scale * (D.T @ D) + 1e-6 * scale * np.eye(gy * gx)
    sol = np.linalg.solve(M, A.T @ r)
    return sol.reshape(gy, gx, 2)


def check_residual(ctrl, n_planes: int, where: str = "residual_cam") -> np.ndarray:
    """``ctrl`` as (n_planes, gy, gx, 2) float64 with finite values and >= 4 points per axis;
    InputError naming the problem otherwise."""
    c = np.asarray(ctrl, np.float64)
    if c.ndim != 4 or c.shape[0] != n_planes or c.shape[3] != 2 or min(c.shape[1:3]) < 4:
        raise InputError(f"{where} must have shape (n_planes={n_planes}, gy >= 4, gx >= 4, 2); "
                         f"got {c.shape}")
    if not np.isfinite(c).all():
        raise InputError(f"{where} contains NaN or infinite values; recalibrate the geometry")
    return c


def proj_from_cam(H_proj_from_cam: np.ndarray, ctrl: np.ndarray, pts_cam_xy: np.ndarray,
                  projector_size: tuple[int, int], iterations: int = 8) -> np.ndarray:
    """(N, 2) projector points whose camera points (homography plus residual ``ctrl``) are
    ``pts_cam_xy``: fixed-point steps ``x <- H⁻¹(c - d(x))``, which converge fast because the
    residual changes by far less than a pixel per pixel."""
    c = np.asarray(pts_cam_xy, np.float64).reshape(-1, 2)
    x = apply_h(H_proj_from_cam, c)
    for _ in range(iterations):
        x = apply_h(H_proj_from_cam, c - displacement(ctrl, x[:, 0], x[:, 1], projector_size))
    return x
