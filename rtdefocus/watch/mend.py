"""New calibrations that explain what the watcher saw change: the room light, a knocked
camera or projector, the focus.

Every function returns a new :class:`~rtdefocus.calib.file.Calibration` and never modifies
the one it is given (the compensator in use keeps reading it until the swap); arrays that do
not change are shared between the two.
"""

from __future__ import annotations

import dataclasses
import logging

import cv2
import numpy as np

from ..calib.file import Calibration
from ..errors import InputError
from ..planar import PlaneLayout, apply_h, lit_polygon, normalise_line

log = logging.getLogger(__name__)


def _translation(d) -> np.ndarray:
    """3×3 homography x -> x + d."""
    return np.array([[1.0, 0.0, d[0]], [0.0, 1.0, d[1]], [0.0, 0.0, 1.0]])


def _derive(calib: Calibration, **changes) -> Calibration:
    """A copy of ``calib`` with ``changes`` (fresh caches, no diagnostics picture)."""
    meta = dict(calib.meta)
    meta["watched"] = int(meta.get("watched", 0)) + 1
    out = dataclasses.replace(calib, meta=meta, **changes)
    out.geometry_detail = None
    return out


# ---------------------------------------------------------------------------- light
def mend_light(calib: Calibration, gain: float, ambient_added: float) -> Calibration:
    """The calibration with its radiometry re-estimated from a residual report: the camera
    sees ``gain`` times the predicted light plus ``ambient_added`` of room light (mean camera
    linear light) in the shape of the calibrated ambient (uniform where none was measured).

    ``albedo' = gain · albedo``, ``ambient' = gain · ambient + ambient_added · shape``.
    """
    if not (np.isfinite(gain) and gain > 0 and np.isfinite(ambient_added)):
        raise InputError(f"a light mend needs a finite gain > 0 and a finite added ambient; got "
                         f"gain={gain!r}, ambient_added={ambient_added!r}")
    wp, hp = calib.projector_size
    albedo = calib.albedo_proj if calib.albedo_proj is not None else np.ones((hp, wp, 3), np.float32)
    ambient = calib.ambient_proj if calib.ambient_proj is not None else np.zeros((hp, wp, 3), np.float32)
    level = float(ambient.mean())
    shape = ambient / level if level > 1e-6 else np.ones_like(ambient)
    return _derive(calib, albedo_proj=(albedo * np.float32(gain)).astype(np.float32),
                   ambient_proj=(ambient * np.float32(gain)
                                 + np.float32(ambient_added) * shape).astype(np.float32))


# ---------------------------------------------------------------------------- geometry
def camera_motion(calib: Calibration, shifts_proj: np.ndarray) -> np.ndarray:
    """(n, 2) camera px: each plane's content shift (projector px) as a camera-space motion at
    the plane's centre (the homography's Jacobian there); NaN rows stay NaN."""
    out = np.full((calib.n_planes, 2), np.nan)
    plane = calib.plane_map()
    for p in range(calib.n_planes):
        ys, xs = np.nonzero(plane == p)
        if not xs.size or not np.all(np.isfinite(shifts_proj[p])):
            continue
        c = np.array([[xs.mean(), ys.mean()]])
        out[p] = (apply_h(calib.H_cam_from_proj[p], c) - apply_h(calib.H_cam_from_proj[p],
                                                                   c - shifts_proj[p]))[0]
    return out


def mend_camera(calib: Calibration, shift_cam) -> Calibration:
    """The calibration after the camera turned so that its view moved by ``shift_cam`` =
    (dx, dy) camera px, or by a 3×3 camera homography (old camera px -> new): one camera-side
    correction for every plane. The projector and the walls did not move, so everything in
    projector space stays (the warp shows the content where it was on the wall)."""
    shift_cam = np.asarray(shift_cam, np.float64)
    C = shift_cam if shift_cam.shape == (3, 3) else _translation(shift_cam)
    if not np.all(np.isfinite(C)):
        raise InputError(f"a camera mend needs a finite shift (2,) or homography (3, 3); got "
                         f"shape {shift_cam.shape}")
    C_inv = np.linalg.inv(C)
    H = np.einsum("ij,njk->nik", C, calib.H_cam_from_proj)
    H_inv = np.einsum("nij,jk->nik", calib.H_proj_from_cam, C_inv)
    folds_cam = np.array([normalise_line(C_inv.T @ f) for f in calib.folds_cam]).reshape(-1, 3)
    return _derive(calib, H_cam_from_proj=H, H_proj_from_cam=H_inv / H_inv[:, 2:3, 2:3],
                   folds_cam=folds_cam, lit_polygon_cam=apply_h(C, calib.lit_polygon_cam))


def camera_correction(old: Calibration, new: Calibration) -> np.ndarray | None:
    """The camera homography ``C`` (old camera px -> new) when ``new`` is ``old`` after a camera
    mend alone (:func:`mend_camera`: one ``C`` for every plane, the projector's folds
    unchanged); None for any other change, or none."""
    if not np.array_equal(np.asarray(old.folds_proj), np.asarray(new.folds_proj)):
        return None
    cs = [n @ np.linalg.inv(o) for o, n in zip(old.H_cam_from_proj, new.H_cam_from_proj,
                                               strict=True)]
    cs = [c / c[2, 2] for c in cs]
    if (not all(np.allclose(c, cs[0], atol=1e-6) for c in cs)
            or np.allclose(cs[0], np.eye(3), atol=1e-9)):
        return None
    return cs[0]


def _shift_per_plane(field: np.ndarray, plane: np.ndarray, motions: np.ndarray,
                     nearest: bool) -> np.ndarray:
    """``field`` (Hp, Wp[, C]) resampled so that pixel y of plane p takes the old value at
    M_p(y) (what the wall under y was lit by before the projector moved); ``motions``
    (n, 3, 3)."""
    hp, wp = field.shape[:2]
    ys, xs = np.mgrid[0:hp, 0:wp].astype(np.float64)
    map_x, map_y = xs.astype(np.float32), ys.astype(np.float32)
    for p, M in enumerate(motions):
        sel = plane == p
        moved = apply_h(M, np.stack([xs[sel], ys[sel]], axis=1))
        map_x[sel], map_y[sel] = moved[:, 0], moved[:, 1]
    interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    # Channel by channel in float32 (remap takes neither int32 nor many channels; indices
    # below 2**24 are exact in float32).
    flat = field.reshape(hp, wp, -1)
    chans = [cv2.remap(np.ascontiguousarray(flat[..., i], np.float32), map_x, map_y, interp,
                       borderMode=cv2.BORDER_REPLICATE) for i in range(flat.shape[2])]
    return np.stack(chans, axis=2).reshape(field.shape).astype(field.dtype)


def mend_projector(calib: Calibration, motions: np.ndarray) -> Calibration:
    """The calibration after the projector moved: one correction per plane, the folds kept
    consistent.

    ``motions``: per plane, the content's shift ``(n, 2)`` = (dx, dy) projector px (as the
    residual report measures it: ``M_p(y) = y + d``), or a homography ``(n, 3, 3)`` M_p:
    plane p's projector pixel y now lights the wall point that
    M_p(y) lit before, so ``H_cam_from_proj'_p = H_cam_from_proj_p · M_p``. The walls
    did not move: each fold's camera line stays, and its projector line is the one both
    neighbouring planes' new homographies agree on best (the mean of the two pull-backs).
    The maps of the wall (albedo, ambient, the kernel field) move with the wall: pixel y
    takes the value of M_p(y).
    """
    m = np.asarray(motions, np.float64)
    if m.shape == (calib.n_planes, 2):
        m = np.stack([_translation(d) for d in m])
    if m.shape != (calib.n_planes, 3, 3) or not np.all(np.isfinite(m)):
        raise InputError(f"a projector mend needs a finite shift (n, 2) or homography (n, 3, 3) "
                         f"for each of the {calib.n_planes} planes; got shape {m.shape}")
    H = np.einsum("nij,njk->nik", calib.H_cam_from_proj, m)
    H_inv = np.einsum("nij,njk->nik", np.linalg.inv(m), calib.H_proj_from_cam)
    folds_proj = []
    for f, (a, b) in zip(calib.folds_cam, calib.fold_planes, strict=True):
        la, lb = normalise_line(H[a].T @ f), normalise_line(H[b].T @ f)
        ref = normalise_line(calib.folds_proj[len(folds_proj)])
        # The same orientation as the calibrated fold (plane a stays on its negative side).
        la = la if la[:2] @ ref[:2] >= 0 else -la
        lb = lb if lb[:2] @ ref[:2] >= 0 else -lb
        folds_proj.append(normalise_line(0.5 * (la + lb)))
    folds_proj = np.array(folds_proj, np.float64).reshape(-1, 3)
    layout = PlaneLayout(calib.n_planes, folds_proj, calib.fold_planes)
    changes = {"H_cam_from_proj": H, "H_proj_from_cam": H_inv / H_inv[:, 2:3, 2:3],
               "folds_proj": folds_proj,
               "lit_polygon_cam": lit_polygon(calib.projector_size, H, layout)}
    new_plane = (np.zeros(calib.plane_map().shape, np.int8) if calib.n_planes == 1 else
                 layout.label(*np.mgrid[0:calib.projector_size[1], 0:calib.projector_size[0]][::-1]))
    for name in ("albedo_proj", "ambient_proj"):
        value = getattr(calib, name)
        if value is not None:
            changes[name] = _shift_per_plane(value, new_plane, m, nearest=False)
    if calib.has_psf:
        changes["pix_idx"] = _shift_per_plane(calib.pix_idx, new_plane, m, nearest=True)
        changes["pix_wts"] = _shift_per_plane(calib.pix_wts, new_plane, m, nearest=True)
        pts = calib.psf_points_proj.astype(np.float64).copy()
        for p in range(calib.n_planes):
            sel = calib.psf_plane == p
            pts[sel] = apply_h(np.linalg.inv(m[p]), pts[sel])
        changes["psf_points_proj"] = pts.astype(np.float32)
    return _derive(calib, **changes)


# ---------------------------------------------------------------------------- focus
def rescale_kernels(calib: Calibration, scale: float) -> Calibration:
    """The calibration with every kernel's radius scaled by ``scale`` (the focus ring turned):
    each PSF zoomed about its centre (cubic), on a support grown to hold it, and renormalised
    to unit sum. The kernel field (which PSFs blend at each pixel) stays. Kernels of a pixel or
    two are only roughly zoomed: the pixel grid, which does not scale, dominates their shape."""
    if not calib.has_psf:
        raise InputError("rescale_kernels needs the calibration's kernels (its PSF section)")
    scale = float(scale)
    if not (np.isfinite(scale) and 0.25 <= scale <= 4.0):
        raise InputError(f"kernel scale must be within [0.25, 4]; got {scale!r}")
    out = _zoom_all(np.asarray(calib.psfs, np.float32), scale)
    return _derive(calib, psfs=out)


def _zoom_all(psfs: np.ndarray, scale: float) -> np.ndarray:
    """(n, k, k) kernels zoomed about their centres by ``scale`` (cubic point samples, unit
    sum), on a common support grown to hold them."""
    n, k, _ = psfs.shape
    k_new = max(k, int(2 * np.ceil(0.5 * (k - 1) * scale) + 1))
    c_old, c_new = 0.5 * (k - 1), 0.5 * (k_new - 1)
    # Point samples of the zoomed kernel, cubic (the identity at scale 1; area sampling of an
    # interpolated kernel would widen kernels of a pixel or two by the interpolation itself).
    # New tap m reads the old kernel at c_old + (m − c_new) / scale.
    off = c_old - c_new / scale
    M = np.float32([[1.0 / scale, 0.0, off], [0.0, 1.0 / scale, off]])
    out = np.empty((n, k_new, k_new), np.float32)
    for i in range(n):
        z = cv2.warpAffine(psfs[i], M, (k_new, k_new), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP,
                           borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
        z = np.clip(z, 0.0, None)            # cubic overshoot
        s = float(z.sum())
        if s > 0:
            out[i] = z / s
        else:                      # a kernel too small to sample: a delta
            out[i] = 0.0
            out[i, k_new // 2, k_new // 2] = 1.0
    return out


def _pad_to(psfs: np.ndarray, k: int) -> np.ndarray:
    n, kk, _ = psfs.shape
    out = np.zeros((n, k, k), np.float32)
    o = (k - kk) // 2
    out[:, o:o + kk, o:o + kk] = psfs
    return out


def _optical_radius(psf: np.ndarray) -> float:
    """A kernel's blur radius with its pixel's own spread taken out: the equivalent disc
    radius of a kernel sampled on pixels is sqrt(r² + 1/3) (a pixel's variance, 1/6 in
    u² + v²), which does not scale with r."""
    from ..calib.psf.dots import equivalent_radius

    return float(np.sqrt(max(equivalent_radius(psf) ** 2 - 1.0 / 3.0, 0.0)))


def rescale_radii(calib: Calibration, scale: float) -> Calibration:
    """The calibration with every pixel's blur radius scaled by ``scale``, its kernel taken
    from the calibration's own kernels by radius (a thin lens's kernel is a function of its
    blur radius, so the measured kernel of the new radius is the right one; pixel-sized
    kernels zoom badly, see :func:`rescale_kernels`).

    The kernels are ordered by equivalent radius; each pixel's radius is its kernel field's
    blend of theirs, and its new kernel the blend of the two whose radii bracket ``scale``
    times it. Radii beyond the family's range take the nearest end kernel zoomed
    (:func:`rescale_kernels`' zoom), added to the family. The family is one for the whole
    frame: a field that blends kernels of several sample points or planes of one radius
    becomes a blend of the two nearest in radius."""
    if not calib.has_psf:
        raise InputError("rescale_radii needs the calibration's kernels (its PSF section)")
    scale = float(scale)
    if not (np.isfinite(scale) and 0.25 <= scale <= 4.0):
        raise InputError(f"radius scale must be within [0.25, 4]; got {scale!r}")
    psfs = np.asarray(calib.psfs, np.float32)
    radius = np.array([_optical_radius(p) for p in psfs])
    idx, wts = np.asarray(calib.pix_idx), np.asarray(calib.pix_wts, np.float32)
    r_pix = np.einsum("hwj,hwj->hw", wts, radius[idx].astype(np.float32))
    target = scale * r_pix
    lo_i, hi_i = int(np.argmin(radius)), int(np.argmax(radius))
    extra = []
    # Zoomed copies of the end kernels, 3 % apart, cover radii beyond the family's range.
    # (a kernel of no measurable radius, a delta, has nothing to zoom)
    for end, reach in ((hi_i, float(target.max()) / max(radius[hi_i], 1e-6)),
                       (lo_i, float(target.min()) / max(radius[lo_i], 1e-6))):
        if radius[end] > 0.1 and ((reach > 1.0 and end == hi_i) or (reach < 1.0 and end == lo_i)):
            reach = min(max(reach, 0.25), 4.0)
            steps = int(np.ceil(abs(np.log(reach)) / np.log(1.03)))
            for f in np.exp(np.linspace(0.0, np.log(reach), steps + 1)[1:]):
                extra.append((end, float(f)))
    family = [psfs]
    for end, f in extra:
        family.append(_zoom_all(psfs[end:end + 1], f))
    k = max(p.shape[1] for p in family)
    fam = np.concatenate([_pad_to(p, k) for p in family]).astype(np.float32)
    fam_r = np.array([_optical_radius(p) for p in fam])
    order = np.argsort(fam_r, kind="stable")
    # strictly increasing radii (kernels of one radius are one entry)
    keep = np.concatenate([[True], np.diff(fam_r[order]) > 1e-6])
    order = order[keep]
    R = fam_r[order]
    j = np.clip(np.searchsorted(R, target), 1, len(R) - 1)
    t = np.clip((target - R[j - 1]) / (R[j] - R[j - 1]), 0.0, 1.0).astype(np.float32)
    new_idx = np.zeros_like(idx)
    new_wts = np.zeros_like(wts)
    new_idx[..., 0], new_idx[..., 1] = order[j - 1], order[j]
    new_wts[..., 0], new_wts[..., 1] = 1.0 - t, t
    # A zoomed end kernel keeps the point and plane it was measured at.
    src = np.array(list(range(len(psfs))) + [end for end, _ in extra], int)
    return _derive(calib, psfs=fam, pix_idx=new_idx.astype(idx.dtype), pix_wts=new_wts,
                   psf_points_proj=np.asarray(calib.psf_points_proj)[src],
                   psf_plane=np.asarray(calib.psf_plane)[src])
