"""Step 6 of the PSF stage: the kernel field F, per projector pixel <= 4 PSF indices and
weights (:func:`interpolation_field`; see :mod:`rtdefocus.calib.psf`)."""

from __future__ import annotations

import numpy as np

from ...checks import check_choice
from ...errors import CalibrationError
from ..file import Calibration
from .pilot import fold_code
from .sampling import SamplePlan

__all__ = ["interpolation_field"]


def _barycentric(pix: np.ndarray, samples: np.ndarray, ids: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Barycentric weights on a Delaunay triangulation of ``samples``; outside the hull, the
    nearest point of the nearest hull edge (clamped extrapolation). Returns (M, 4) idx, wts."""
    # scipy loads on first use (~1 s): `import rtdefocus.calib` (the player loads Calibration) stays fast.
    from scipy.spatial import Delaunay, QhullError

    M = len(pix)
    idx = np.zeros((M, 4), np.int32)
    wts = np.zeros((M, 4), np.float32)
    if len(samples) == 1:
        idx[:, 0], wts[:, 0] = ids[0], 1.0
        return idx, wts
    try:
        tri = Delaunay(samples)
        simp = tri.find_simplex(pix)
        edges = tri.convex_hull
    except (QhullError, ValueError):      # collinear samples: blend along the polyline
        order = np.argsort(samples[:, 0] + 1e-3 * samples[:, 1])
        edges = np.column_stack([order[:-1], order[1:]])
        simp = np.full(M, -1)
    inside = simp >= 0
    if inside.any():
        T = tri.transform[simp[inside]]
        bc = np.einsum("mij,mj->mi", T[:, :2], pix[inside] - T[:, 2])
        w = np.column_stack([bc, 1 - bc.sum(axis=1)])
        w = np.clip(w, 0, None)
        w /= w.sum(axis=1, keepdims=True)
        idx[inside, :3] = ids[tri.simplices[simp[inside]]]
        wts[inside, :3] = w
    out = np.flatnonzero(~inside)
    if len(out):
        A, B = samples[edges[:, 0]], samples[edges[:, 1]]
        AB = B - A
        L2 = np.maximum((AB ** 2).sum(1), 1e-12)
        for chunk in np.array_split(out, max(1, len(out) // 20000 + 1)):
            P = pix[chunk]
            t = np.clip(((P[:, None, :] - A[None]) * AB[None]).sum(-1) / L2[None], 0, 1)
            Q = A[None] + t[..., None] * AB[None]
            d2 = ((P[:, None, :] - Q) ** 2).sum(-1)
            e = d2.argmin(axis=1)
            te = t[np.arange(len(chunk)), e]
            idx[chunk, 0] = ids[edges[e, 0]]
            idx[chunk, 1] = ids[edges[e, 1]]
            wts[chunk, 0] = 1 - te
            wts[chunk, 1] = te
    return idx, wts


def _inverse_bilinear(quad: np.ndarray, pix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(s, t) in [0, 1]² (clamped) with bilinear(quad; s, t) = pix; quad (4, 2) cyclic order."""
    p00, p10, p11, p01 = quad
    s = np.full(len(pix), 0.5)
    t = np.full(len(pix), 0.5)
    for _ in range(12):
        P = ((1 - s) * (1 - t))[:, None] * p00 + (s * (1 - t))[:, None] * p10 + \
            (s * t)[:, None] * p11 + ((1 - s) * t)[:, None] * p01
        ds = (1 - t)[:, None] * (p10 - p00) + t[:, None] * (p11 - p01)
        dt = (1 - s)[:, None] * (p01 - p00) + s[:, None] * (p11 - p10)
        r = pix - P
        det = ds[:, 0] * dt[:, 1] - ds[:, 1] * dt[:, 0]
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        us = (r[:, 0] * dt[:, 1] - r[:, 1] * dt[:, 0]) / det
        ut = (ds[:, 0] * r[:, 1] - ds[:, 1] * r[:, 0]) / det
        s, t = s + us, t + ut
        if max(np.abs(us).max(), np.abs(ut).max()) < 1e-7:   # Newton: a few steps suffice
            break
    return np.clip(s, 0, 1), np.clip(t, 0, 1)


def _bilinear_weights(quad_ids: list, quad: np.ndarray, pix: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
    s, t = _inverse_bilinear(quad, pix)
    w = np.column_stack([(1 - s) * (1 - t), s * (1 - t), s * t, (1 - s) * t]).astype(np.float32)
    idx = np.tile(np.asarray(quad_ids, np.int32), (len(pix), 1))
    return idx, w


def interpolation_field(calib: Calibration, plan: SamplePlan, *, mode: str | None = None
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Per projector pixel, ≤ 4 PSF indices and weights (step 6).

    Parameters
    ----------
    calib : Calibration (geometry); its plane layout decides each pixel's plane.
    plan : the samples (PSF i is measured at ``plan.points[i]``).
    mode : ``"planes"`` (per-plane blending; bilinear quads for ``paper``, else triangles),
        ``"cross"`` (one triangulation of all samples, ignoring the planes); default from the
        plan (``cross`` when ``plan.cross_fold``).

    Returns
    -------
    idx : (Hp, Wp, 4) int32, wts : (Hp, Wp, 4) float32 (rows sum to 1, unused slots 0).
    """
    mode = mode or ("cross" if plan.cross_fold else "planes")
    check_choice(mode, ("planes", "cross"), "mode")
    wp, hp = calib.projector_size
    ys, xs = np.mgrid[0:hp, 0:wp]
    pix_all = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    idx = np.zeros((hp * wp, 4), np.int32)
    wts = np.zeros((hp * wp, 4), np.float32)
    pts = plan.points.astype(np.float64)
    if mode == "cross" or calib.n_planes == 1:
        regions = {0: np.ones(hp * wp, bool)}
        members = {0: np.arange(len(pts))}
    else:
        # Each plane blends its own samples and those on its folds, never another plane's.
        plane = calib.plane_map().ravel()
        regions = {p: plane == p for p in range(calib.n_planes)}
        members = {p: np.flatnonzero((plan.planes == p) | np.isin(
            plan.planes, [fold_code(j) for j in calib.layout.bounding_folds(p)]))
            for p in range(calib.n_planes)}
    for p, sel in regions.items():
        ids = members[p]
        if len(ids) == 0:
            raise CalibrationError(f"no PSF sample on plane {p}; cannot build its kernels")
        pix = pix_all[sel]
        quads = plan.quads.get(p) if (plan.layout == "paper" and mode == "planes") or (
            plan.layout == "paper" and plan.cross_fold) else None
        if quads:
            out_i = np.zeros((len(pix), 4), np.int32)
            out_w = np.zeros((len(pix), 4), np.float32)
            main = quads[0][1]
            use_strip = np.zeros(len(pix), bool)
            if len(quads) > 1:
                strip = quads[1][1]
                a, b = pts[strip[0]], pts[strip[1]]
                # Pixels beyond the line through the fold-side corners (towards the fold).
                n = np.array([a[1] - b[1], b[0] - a[0]])
                inward = calib.layout.inward(fold_code(plan.planes[strip[2]]), p)
                if n @ inward < 0:
                    n = -n
                use_strip = (pix - a) @ n < 0
                si, sw = _bilinear_weights(strip, pts[strip], pix[use_strip])
                out_i[use_strip], out_w[use_strip] = si, sw
            mi, mw = _bilinear_weights(main, pts[main], pix[~use_strip])
            out_i[~use_strip], out_w[~use_strip] = mi, mw
            idx[sel], wts[sel] = out_i, out_w
        else:
            M = plan.metric.get(p, np.eye(2)) if mode == "planes" or plan.cross_fold else np.eye(2)
            i_, w_ = _barycentric(pix @ M.T, pts[ids] @ M.T, ids.astype(np.int32))
            idx[sel], wts[sel] = i_, w_
    wts /= np.maximum(wts.sum(axis=1, keepdims=True), 1e-12)
    idx[wts == 0] = 0
    return idx.reshape(hp, wp, 4), wts.reshape(hp, wp, 4)
