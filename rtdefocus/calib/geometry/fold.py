"""Kinks -> the fold: steps 2, 3 and 6 of the geometry stage (:mod:`.geometry`).

A projected straight line crossing the fold is two straight segments in the camera. Per line a
*hinge* model (a quadratic plus a slope change at one place) is compared with a *cubic* (a
smooth bend everywhere, as lens distortion makes): a kink is where the hinge fits much better
*and* the direction changes by a real angle (:func:`find_kink`). The camera fold is a robust line
through the kinks (:func:`fit_fold`); the projector fold is its image through each plane's
inverse homography (:func:`fold_to_projector`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ...planar import apply_h, line_eval, normalise_line, tls_line

__all__ = ["Kink", "find_kink", "find_kinks", "fit_fold", "fold_to_projector"]


# --------------------------------------------------------------------------- kinks
@dataclass
class Kink:
    """A sharp change of direction on one detected line.

    Attributes
    ----------
    point_cam_xy : (2,) float64 camera point of the bend.
    angle_deg : direction change (degrees).
    score : how much better the hinge fits than the smooth cubic, in units of the noise
        variance ((RSS_cubic − RSS_hinge) / σ²).
    line : index of the line in :attr:`LineDetection.lines`.
    """

    point_cam_xy: np.ndarray
    angle_deg: float
    score: float
    line: int = -1


def _hinge_rss(u: np.ndarray, s: np.ndarray, taus: np.ndarray):
    """RSS and coefficients of ``s = c0 + c1 u + c2 u² + d·max(0, u − τ)`` for every τ."""
    base = np.stack([np.ones_like(u), u, u * u], axis=1)                    # (n, 3)
    hinge = np.maximum(0.0, u[None, :] - taus[:, None])                      # (m, n)
    m = len(taus)
    mean = s.mean()
    s = s - mean                  # centred: keeps |s|² − βᵀAᵀs free of cancellation
    # Normal equations per τ from shared pieces (matrix products, no (m, n, 4) array).
    AtA = np.empty((m, 4, 4))
    AtA[:, :3, :3] = base.T @ base
    hb = hinge @ base                                                        # (m, 3)
    AtA[:, :3, 3] = hb
    AtA[:, 3, :3] = hb
    AtA[:, 3, 3] = (hinge * hinge).sum(axis=1)
    Atb = np.empty((m, 4))
    Atb[:, :3] = base.T @ s
    Atb[:, 3] = hinge @ s
    beta = np.linalg.solve(AtA + 1e-12 * np.eye(4), Atb[..., None])[..., 0]
    rss = s @ s - (beta * Atb).sum(axis=1)        # least squares: |s|² − βᵀAᵀs
    beta[:, 0] += mean
    return np.maximum(rss, 0.0), beta


def find_kink(t: np.ndarray, s: np.ndarray, *, min_angle_deg: float = 1.0, min_score: float = 200.0,
              min_side: float = 0.0, min_points: int = 20) -> Kink | None:
    """Find one sharp bend on a line sampled as ``s(t)`` (camera px), or None.

    Parameters
    ----------
    t : (n,) positions along the line (camera row for a near-vertical line, column otherwise).
    s : (n,) float positions across it.
    min_angle_deg : smallest direction change accepted as a kink.
    min_score : smallest (RSS_cubic − RSS_hinge) / σ² accepted; a smooth lens-distortion bend
        is fitted as well by the cubic as by the hinge and scores near 0.
    min_side : the bend must have at least this fraction of the points on each side.
    min_points : and at least this many (a fold near the frame edge still gives a kink).

    Returns
    -------
    Kink or None (``line`` left at -1).
    """
    t = np.asarray(t, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)
    n = t.size
    if n < 2 * min_points + 5:
        return None
    t0, th = 0.5 * (t.min() + t.max()), 0.5 * (t.max() - t.min())
    if th <= 0:
        return None
    u = (t - t0) / th
    keep = np.ones(n, bool)
    best = None
    for _ in range(2):          # fit, drop gross outliers (> 5 robust sigma), fit again
        uk, sk = u[keep], s[keep]
        nk = uk.size
        lo_i = max(int(min_side * nk), min_points)
        hi_i = nk - 1 - lo_i
        if hi_i <= lo_i:
            return None
        su = np.sort(uk)
        taus = np.linspace(su[lo_i], su[hi_i], 48)
        rss, beta = _hinge_rss(uk, sk, taus)
        i = int(np.argmin(rss))
        if i in (0, len(taus) - 1):
            return None         # best at the edge of the search: the bend (if any) is off it
        # Zoom in on the minimum: each pass searches ±1 step of the previous grid, 40x finer.
        lo_t, hi_t = taus[i - 1], taus[i + 1]
        for _ in range(2):
            fine = np.linspace(lo_t, hi_t, 41)
            frss, fbeta = _hinge_rss(uk, sk, fine)
            j = int(np.argmin(frss))
            lo_t, hi_t = fine[max(j - 1, 0)], fine[min(j + 1, len(fine) - 1)]
        tau, b, rss_h = fine[j], fbeta[j], frss[j]
        resid = sk - (b[0] + b[1] * uk + b[2] * uk * uk + b[3] * np.maximum(0.0, uk - tau))
        sigma = 1.4826 * np.median(np.abs(resid)) + 1e-6
        best = (tau, b, rss_h, uk, sk)
        new_keep = np.zeros(n, bool)
        full_res = s - (b[0] + b[1] * u + b[2] * u * u + b[3] * np.maximum(0.0, u - tau))
        new_keep[np.abs(full_res) < 5 * sigma] = True
        if new_keep.sum() == keep.sum() or new_keep.sum() < 2 * min_points + 5:
            break
        keep = new_keep
    tau, b, rss_h, uk, sk = best
    V = np.stack([np.ones_like(uk), uk, uk ** 2, uk ** 3], axis=1)
    coef, *_ = np.linalg.lstsq(V, sk, rcond=None)
    rss_c = float(((sk - V @ coef) ** 2).sum())
    dof = max(uk.size - 5, 1)
    var = max(rss_h / dof, 1e-6)
    score = (rss_c - rss_h) / var
    slope_l = (b[1] + 2 * b[2] * tau) / th          # ds/dt just before the bend
    slope_r = slope_l + b[3] / th
    angle = math.degrees(abs(math.atan(slope_r) - math.atan(slope_l)))
    if angle < min_angle_deg or score < min_score:
        return None
    tk = t0 + tau * th
    sk_val = b[0] + b[1] * tau + b[2] * tau * tau
    return Kink(point_cam_xy=np.array([tk, sk_val]), angle_deg=angle, score=float(score))


def find_kinks(t: np.ndarray, s: np.ndarray, *, min_angle_deg: float = 1.0, gap: float = 24.0,
               max_kinks: int = 4) -> list[Kink]:
    """Every sharp bend on a line that crosses several folds, in order along ``t``.

    The strongest bend is found on the whole line (:func:`find_kink`), then each side of it
    (``gap`` camera px away, clear of the blurred transition) is searched again. Each bend is
    finally re-located on the stretch between its neighbours, so another bend never pulls it.
    A line with one bend gets exactly what :func:`find_kink` gives.
    """
    t = np.asarray(t, dtype=np.float64)
    s = np.asarray(s, dtype=np.float64)
    found: list[Kink] = []

    def search(lo: float, hi: float) -> None:
        if len(found) >= max_kinks:
            return
        sel = (t >= lo) & (t <= hi)
        kk = find_kink(t[sel], s[sel], min_angle_deg=min_angle_deg)
        if kk is None:
            return
        found.append(kk)
        tk = float(kk.point_cam_xy[0])
        search(lo, tk - gap)
        search(tk + gap, hi)

    search(-np.inf, np.inf)
    if len(found) < 2:
        return found
    pos = sorted(float(kk.point_cam_xy[0]) for kk in found)
    out = []
    for i in range(len(pos)):
        lo = pos[i - 1] + gap if i > 0 else -np.inf
        hi = pos[i + 1] - gap if i + 1 < len(pos) else np.inf
        sel = (t >= lo) & (t <= hi)
        kk = find_kink(t[sel], s[sel], min_angle_deg=min_angle_deg)
        if kk is not None:
            out.append(kk)
    return out


# --------------------------------------------------------------------------- fold
def fit_fold(points_xy: np.ndarray, *, tol: float = 3.0, min_inliers: int = 5,
             min_inlier_fraction: float = 0.5, seed: int = 0):
    """Robust line through kink points: RANSAC over pairs, then total least squares.

    Parameters
    ----------
    points_xy : (m, 2) camera points of the kinks.
    tol : RANSAC inlier distance (camera px).
    min_inliers, min_inlier_fraction : fewer consistent kinks than this means "no fold".

    Returns
    -------
    (line (3,) float64 normalised, inliers (m,) bool, rms float) or None when no fold is found.
    """
    pts = np.asarray(points_xy, dtype=np.float64).reshape(-1, 2)
    m = len(pts)
    if m < min_inliers:
        return None
    rng = np.random.default_rng(seed)
    if m * (m - 1) // 2 <= 2000:
        i, j = np.triu_indices(m, 1)
    else:
        i = rng.integers(0, m, 2000)
        j = rng.integers(0, m, 2000)
        ok = i != j
        i, j = i[ok], j[ok]
    d = pts[j] - pts[i]
    nrm = np.hypot(d[:, 0], d[:, 1])
    ok = nrm > 1e-9
    i, j, d, nrm = i[ok], j[ok], d[ok], nrm[ok]
    normals = np.stack([-d[:, 1], d[:, 0]], axis=1) / nrm[:, None]
    c = -(normals * pts[i]).sum(axis=1)
    dist = np.abs(pts @ normals.T + c[None, :])            # (m, pairs)
    counts = (dist < tol).sum(axis=0)
    if counts.size == 0:
        return None
    best = int(np.argmax(counts))
    inl = dist[:, best] < tol
    line = None
    for _ in range(3):              # least squares on the inliers, then re-select them
        if inl.sum() < 2:
            return None
        line = tls_line(pts[inl])
        r = np.abs(line_eval(line, pts))
        new = r < tol
        if np.array_equal(new, inl):
            break
        inl = new
    if inl.sum() < min_inliers or inl.sum() < min_inlier_fraction * m:
        return None
    rms = float(np.sqrt(np.mean(line_eval(line, pts[inl]) ** 2)))
    return normalise_line(line), inl, rms


def fold_to_projector(fold_cam: np.ndarray, H_proj_from_cam: np.ndarray,
                      segment_cam: np.ndarray, to_proj=None):
    """The projector fold from the camera fold and each plane's inverse homography.

    Parameters
    ----------
    fold_cam : (3,) camera fold line.
    H_proj_from_cam : (2, 3, 3).
    segment_cam : (2, 2) ends of the visible part of the camera fold.
    to_proj : optional pair of functions, camera points (N, 2) -> projector points, one per
        plane, used instead of the inverse homographies (planes with a residual field).

    Returns
    -------
    fold_proj : (3,) float64 normalised (orientation not yet fixed).
    disagreement : float, largest distance (projector px) between the two planes' images of the
        visible fold segment, measured at its ends.
    """
    ts = np.linspace(0.0, 1.0, 21)
    seg = segment_cam[0][None, :] * (1 - ts[:, None]) + segment_cam[1][None, :] * ts[:, None]
    if to_proj is None:
        m0 = apply_h(H_proj_from_cam[0], seg)
        m1 = apply_h(H_proj_from_cam[1], seg)
    else:
        m0, m1 = to_proj[0](seg), to_proj[1](seg)
    line = normalise_line(tls_line(np.concatenate([m0, m1])))
    l0 = normalise_line(tls_line(m0))
    # Largest distance between the two mapped lines over the visible segment (at its ends,
    # where two lines are farthest apart).
    ends = np.stack([m0[0], m0[-1], m1[0], m1[-1]])
    l1 = normalise_line(tls_line(m1))
    dis = max(float(np.abs(line_eval(l1, ends[:2])).max()),
              float(np.abs(line_eval(l0, ends[2:])).max()))
    return line, dis

