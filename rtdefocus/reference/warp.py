"""The warp + stitch, plainly (docs/internals.md, "The warp"): the reference for ``gl/warp.py``.

Per projector pixel (x, y) (centres at integers): plane p from the plane layout
(:meth:`rtdefocus.planar.PlaneLayout.label`: with two planes, 0 where
``fold_proj · (x, y, 1) < 0``, else 1; always 0 with one plane); camera point
``H_cam_from_proj[p] @ (x, y, 1)``
(dehomogenised), plus the plane's smooth residual at that pixel when the calibration has one
(``offset``: (Hp, Wp, 2) float32 camera px, :func:`rtdefocus.residual.dense_displacement`);
input pixel through the display rect (x0, y0, w, h) for an input of W×H::

    u = (xc - x0 + 0.5) * W / w - 0.5          v = (yc - y0 + 0.5) * H / h - 0.5

sampled bilinearly with black outside the input (OpenCV's ``BORDER_CONSTANT`` 0, which is also
GL's ``CLAMP_TO_BORDER`` with a black border: within one input pixel of the edge the sample fades
to black). The output is uint8 in the input's encoding (no linearisation).

Minification — the rule both implementations follow exactly:

* level of detail per pixel, from the analytic Jacobian of that pixel's own plane mapping (not
  from screen-space differences, which jump at the fold and would leave a seam; the
  residual's own slope, a few pixels over hundreds, is left out of it):
  ``lod = log2(max(|∂(u, v)/∂x|, |∂(u, v)/∂y|))`` in input pixels per projector pixel
  (the OpenGL specification's ρ);
* mip levels are used only when some projector pixel has ``lod > 0``; then level L + 1 is level L
  resized with ``cv2.INTER_AREA`` to ``(max(1, W_L // 2), max(1, H_L // 2))``, stored as uint8
  (:func:`mip_pyramid`; the GL pass uploads the very same levels);
* ``lod <= 0``: bilinear on level 0; ``0 < lod < L_max``: trilinear — bilinear on levels
  ``floor(lod)`` and ``floor(lod) + 1`` blended by ``frac(lod)``; ``lod >= L_max``: the last level.
  On level L, texel i is centred at ``(i + 0.5) / W_L`` of the input's width.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from ..errors import InputError, InputTypeError
from ..planar import MAX_PLANES, PlaneLayout

__all__ = ["check_image", "check_offset", "check_warp_inputs", "mip_levels_needed", "mip_pyramid", "warp_cv2",
           "warp_lod", "warp_maps"]


def check_warp_inputs(H_cam_from_proj, planes, rect, projector_size):
    """Validate and normalise the geometry of a warp; raise :class:`InputError` naming the fix.

    Parameters
    ----------
    H_cam_from_proj : array_like, (n, 3, 3) or (3, 3)
        Per-plane homographies, projector pixel -> camera pixel; n is 1 .. MAX_PLANES.
    planes : PlaneLayout, array_like (3,) or None
        The planes in projector pixels: a :class:`~rtdefocus.planar.PlaneLayout`
        (``calib.layout``), or for two planes their fold line ``a x + b y + c = 0``, plane 0
        where negative. Ignored (may be None or zeros) when n = 1.
    rect : sequence of 4 numbers
        Display rectangle ``(x0, y0, w, h)`` in camera pixels (an OpenCV Rect).
    projector_size : (int, int)
        (width, height) of the output.

    Returns
    -------
    H : (n, 3, 3) float64
        Homographies scaled to unit norm with the sign that makes the homogeneous coordinate
        positive at the projector's centre (a homography is defined up to any non-zero factor,
        and "behind the camera" must mean the same thing in every implementation).
    layout : PlaneLayout
    rect : (4,) float64
    projector_size : (int, int)
    """
    H = np.asarray(H_cam_from_proj, dtype=np.float64)
    if H.shape == (3, 3):
        H = H[None]
    if H.ndim != 3 or H.shape[1:] != (3, 3) or not 1 <= H.shape[0] <= MAX_PLANES:
        raise InputError(f"H_cam_from_proj must have shape (n, 3, 3) with n = 1 .. {MAX_PLANES} "
                         f"planes; got {H.shape}")
    if not np.isfinite(H).all():
        raise InputError("H_cam_from_proj contains NaN or infinite values; the geometric "
                         "calibration failed — recalibrate (`rtdefocus calibrate`)")
    try:
        wp, hp = (int(v) for v in projector_size)
    except (TypeError, ValueError):
        raise InputError(f"projector_size must be (width, height); got {projector_size!r}") from None
    if wp <= 0 or hp <= 0:
        raise InputError(f"projector_size must be positive (width, height); got {projector_size}")
    centre = np.array([(wp - 1) / 2.0, (hp - 1) / 2.0, 1.0])
    # Pixel coordinates make H's entries span ~6 orders of magnitude; in units of the frame size
    # (D⁻¹ H D) a real homography has singular values within a few orders of each other, while
    # a singular one has σ_min/σ_max at rounding level (~1e-16).
    D = np.diag([float(max(wp, hp)), float(max(wp, hp)), 1.0])
    out = np.empty_like(H)
    for p, Hp_ in enumerate(H):
        norm = np.linalg.norm(Hp_)
        sv = np.linalg.svd(np.linalg.inv(D) @ Hp_ @ D, compute_uv=False)
        if norm == 0 or sv[-1] <= 1e-9 * sv[0]:
            raise InputError(f"H_cam_from_proj[{p}] is singular (rank < 3), so it maps the projector "
                             f"onto a line or a point: {Hp_.tolist()}; recalibrate the geometry")
        Hn = Hp_ / norm
        z = Hn[2] @ centre
        if z == 0:
            raise InputError(f"H_cam_from_proj[{p}] sends the projector's centre to infinity "
                             f"({Hp_.tolist()}); recalibrate the geometry")
        out[p] = Hn if z > 0 else -Hn
    try:
        layout = PlaneLayout.coerce(planes, out.shape[0])
    except InputError as exc:
        raise InputError(f"planes: {exc}") from None
    r = np.asarray(rect, dtype=np.float64).reshape(-1)
    if r.shape != (4,) or not np.isfinite(r).all() or r[2] <= 0 or r[3] <= 0:
        raise InputError(f"rect must be (x, y, w, h) in camera pixels with w, h > 0; got {rect!r}")
    return out, layout, r, (wp, hp)


def check_image(image) -> np.ndarray:
    """Return ``image`` as an array after checking it is RGB uint8 (H, W, 3); else InputError."""
    if image is None or isinstance(image, (str, bytes)):
        raise InputTypeError(f"image must be an RGB uint8 array (H, W, 3); got {image!r} (read a "
                             "file with rtdefocus.imageio or cv2.imread + cv2.cvtColor BGR2RGB)")
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8 or img.shape[0] < 1 \
            or img.shape[1] < 1:
        if img.size == 0:
            fix = "nothing: the array is empty; check how the frame was read"
        elif img.ndim == 2:
            fix = "a grey image: np.dstack([img] * 3)"
        elif img.ndim == 3 and img.shape[2] == 4:
            fix = "RGBA: drop alpha with img[..., :3]"
        elif img.ndim == 3 and img.shape[2] == 3 and img.dtype.kind == "f":
            fix = "floats in [0, 1]: (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)"
        elif img.ndim == 3 and img.shape[0] == 3 and img.shape[2] != 3:
            fix = "planar (3, H, W): np.moveaxis(img, 0, -1)"
        elif img.ndim == 3 and img.shape[2] == 3:
            fix = "other integers: scale into 0..255 and .astype(np.uint8)"
        else:
            fix = "this array: check how the frame was read"
        raise InputError(f"image must be RGB uint8 of shape (H, W, 3); got {img.dtype} "
                         f"{img.shape}. Convert {fix}")
    return img


def check_offset(offset, projector_size) -> np.ndarray | None:
    """``offset`` as (Hp, Wp, 2) float32 (None stays None); InputError naming the fix."""
    if offset is None:
        return None
    wp, hp = projector_size
    off = np.asarray(offset)
    if off.shape != (hp, wp, 2) or not np.isfinite(off).all():
        raise InputError(f"offset must be a finite (Hp, Wp, 2) = ({hp}, {wp}, 2) array of camera px "
                         f"(calib.residual_dense()); got shape {off.shape}")
    return off.astype(np.float32, copy=False)


def _geometry(H_cam_from_proj, planes, rect, input_size, projector_size, step=1, offset=None):
    """Per projector pixel: u, v (input px), z (homogeneous coordinate) and lod, all float64.
    With ``step`` > 1 only every step-th row and column (and the last ones) are evaluated.
    ``offset`` (Hp, Wp, 2) camera px is added to each pixel's camera point (not to the lod)."""
    H, layout, (x0, y0, w, h), (wp, hp) = check_warp_inputs(H_cam_from_proj, planes, rect,
                                                            projector_size)
    W, Hh = (int(v) for v in input_size)
    cols = np.unique(np.r_[np.arange(0, wp, step), wp - 1]).astype(np.float64)
    rows = np.unique(np.r_[np.arange(0, hp, step), hp - 1]).astype(np.float64)
    xs, ys = np.meshgrid(cols, rows)
    Hpix = H[layout.label(xs, ys)]                                 # (rows, cols, 3, 3)
    m = [[Hpix[..., i, j] for j in range(3)] for i in range(3)]
    X = m[0][0] * xs + m[0][1] * ys + m[0][2]
    Y = m[1][0] * xs + m[1][1] * ys + m[1][2]
    Z = m[2][0] * xs + m[2][1] * ys + m[2][2]
    offset = check_offset(offset, (wp, hp))
    with np.errstate(divide="ignore", invalid="ignore"):
        xc, yc = X / Z, Y / Z
        sx, sy = W / w, Hh / h
        if offset is not None:
            sub = offset[np.ix_(rows.astype(np.intp), cols.astype(np.intp))].astype(np.float64)
            u = (xc + sub[..., 0] - x0 + 0.5) * sx - 0.5
            v = (yc + sub[..., 1] - y0 + 0.5) * sy - 0.5
        else:
            u = (xc - x0 + 0.5) * sx - 0.5
            v = (yc - y0 + 0.5) * sy - 0.5
        # d(xc)/dx = (H00 - xc H20) / Z etc.: the analytic Jacobian of this plane's homography.
        dudx = (m[0][0] - xc * m[2][0]) / Z * sx
        dvdx = (m[1][0] - yc * m[2][0]) / Z * sy
        dudy = (m[0][1] - xc * m[2][1]) / Z * sx
        dvdy = (m[1][1] - yc * m[2][1]) / Z * sy
        rho = np.maximum(np.hypot(dudx, dvdx), np.hypot(dudy, dvdy))
        lod = np.log2(rho)
    return u, v, Z, lod


def warp_maps(H_cam_from_proj, planes, rect, input_size, projector_size, offset=None):
    """Where each projector pixel samples the input.

    Parameters
    ----------
    H_cam_from_proj : (n, 3, 3) float64
        Per-plane homographies, projector pixel -> camera pixel (n = 1 .. MAX_PLANES).
    planes : PlaneLayout, (3,) float64 or None
        The planes (``calib.layout``; for two planes also their fold line, plane 0 where
        negative; ignored for n = 1).
    rect : (x0, y0, w, h)
        Display rectangle in camera pixels.
    input_size : (int, int)
        (W, H) of the input image.
    projector_size : (int, int)
        (Wp, Hp) of the output.
    offset : (Hp, Wp, 2) float32, optional
        Camera px added to each pixel's camera point: the planes' smooth residual
        (``calib.residual_dense()``); None: the homographies alone.

    Returns
    -------
    map_x, map_y : (Hp, Wp) float32
        Input pixel coordinates (u, v) sampled by each projector pixel, for ``cv2.remap``;
        -1e6 where the pixel maps to no camera point (behind the homography's horizon).
    valid : (Hp, Wp) bool
        True where the sample lies inside the input's extent ``[-0.5, W - 0.5] × [-0.5, H - 0.5]``.
        Outside it the warp is black, except for the one-input-pixel fade of the bilinear
        border (``BORDER_CONSTANT``).
    """
    u, v, z, _ = _geometry(H_cam_from_proj, planes, rect, input_size, projector_size,
                           offset=offset)
    W, Hh = input_size
    ok = (z > 0) & np.isfinite(u) & np.isfinite(v)
    valid = ok & (u >= -0.5) & (u <= W - 0.5) & (v >= -0.5) & (v <= Hh - 0.5)
    # Far-away coordinates are clamped (still outside) so float32 and cv2's int conversion stay sane.
    map_x = np.where(ok, np.clip(u, -1e6, 1e6), -1e6).astype(np.float32)
    map_y = np.where(ok, np.clip(v, -1e6, 1e6), -1e6).astype(np.float32)
    return map_x, map_y, valid


def warp_lod(H_cam_from_proj, planes, rect, input_size, projector_size, step=1) -> np.ndarray:
    """(Hp, Wp) float64 level of detail of each projector pixel (see the module docstring):
    > 0 where the input is minified; NaN where the pixel maps to no camera point. ``step`` > 1
    evaluates every step-th row and column only (plus the last), for a quick maximum."""
    _, _, z, lod = _geometry(H_cam_from_proj, planes, rect, input_size, projector_size, step)
    return np.where((z > 0) & np.isfinite(lod), lod, np.nan)


def mip_levels_needed(max_lod: float, input_size) -> int:
    """Number of mip levels (1 = base only) for a frame whose largest level of detail is
    ``max_lod``: 1 when nothing is minified, else the full chain down to 1×1."""
    if not max_lod > 0:
        return 1
    return int(math.floor(math.log2(max(input_size)))) + 1


def mip_pyramid(image: np.ndarray, n_levels: int) -> list[np.ndarray]:
    """``n_levels`` uint8 levels of ``image``: level L+1 = INTER_AREA resize of level L to
    ``(max(1, W_L // 2), max(1, H_L // 2))`` (the sizes OpenGL expects of a mip chain)."""
    levels = [np.ascontiguousarray(image)]
    for _ in range(1, n_levels):
        prev = levels[-1]
        h, w = prev.shape[:2]
        levels.append(cv2.resize(prev, (max(1, w // 2), max(1, h // 2)), interpolation=cv2.INTER_AREA))
    return levels


def _bilinear(level: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear sample of ``level`` (float32 (h, w, 3)) at pixel coordinates (u, v), black outside.

    The four neighbours are fetched with ``cv2.remap`` (nearest, on integer coordinates, with
    ``BORDER_CONSTANT`` 0) and blended with float64 weights: ``cv2.remap(INTER_LINEAR)`` itself
    rounds positions to 1/32 px in OpenCV 4, which is up to 4 LSB on sharp detail.
    """
    h, w = level.shape[:2]
    # Outside by more than a pixel is all border anyway; clamping keeps the int maps in range.
    u = np.clip(np.nan_to_num(u, nan=-2.0), -2.0, w + 1.0)
    v = np.clip(np.nan_to_num(v, nan=-2.0), -2.0, h + 1.0)
    u0, v0 = np.floor(u), np.floor(v)
    fu, fv = (u - u0)[..., None], (v - v0)[..., None]
    out = np.zeros(u.shape + (3,), dtype=np.float64)
    for dv, wv in ((0, 1.0 - fv), (1, fv)):
        for du, wu in ((0, 1.0 - fu), (1, fu)):
            tap = cv2.remap(level, (u0 + du).astype(np.float32), (v0 + dv).astype(np.float32),
                            cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
            out += wu * wv * tap
    return out


def warp_cv2(image: np.ndarray, H_cam_from_proj, planes, rect, projector_size,
             offset=None) -> np.ndarray:
    """Warp ``image`` into projector space: the reference twin of :class:`rtdefocus.gl.warp.GLWarp`.

    Parameters
    ----------
    image : (H, W, 3) uint8
        RGB input, any size.
    H_cam_from_proj : (n, 3, 3) float64
        Per-plane homographies, projector pixel -> camera pixel (n = 1 .. MAX_PLANES).
    planes : PlaneLayout, (3,) float64 or None
        The planes (``calib.layout``; for two planes also their fold line, plane 0 where
        negative; ignored for n = 1).
    rect : (x0, y0, w, h)
        Display rectangle in camera pixels where the input must appear.
    projector_size : (int, int)
        (Wp, Hp).
    offset : (Hp, Wp, 2) float32, optional
        The planes' smooth residual in camera px (``calib.residual_dense()``); None: none.

    Returns
    -------
    (Hp, Wp, 3) uint8
        The projector frame, in the input's encoding; black where no input lands.
    """
    img = check_image(image)
    Hh, W = img.shape[:2]
    u, v, z, lod = _geometry(H_cam_from_proj, planes, rect, (W, Hh), projector_size,
                             offset=offset)
    ok = (z > 0) & np.isfinite(u) & np.isfinite(v)
    u = np.where(ok, u, -2.0)
    v = np.where(ok, v, -2.0)
    lod = np.where(ok & np.isfinite(lod), lod, 0.0)
    n_levels = mip_levels_needed(float(lod[ok].max()) if ok.any() else 0.0, (W, Hh))
    levels = [lv.astype(np.float32) for lv in mip_pyramid(img, n_levels)]
    if n_levels == 1:
        out = _bilinear(levels[0], u, v)
    else:
        top = n_levels - 1
        lam = np.clip(lod, 0.0, top)
        lo = np.floor(lam).astype(np.intp)
        frac = lam - lo
        s, t = (u + 0.5) / W, (v + 0.5) / Hh          # normalised texture coordinates
        out = np.zeros(u.shape + (3,), dtype=np.float64)
        for L in range(n_levels):
            # level L is the lower level of pixels with floor(lod) = L (weight 1 - frac) and
            # the upper level of those with floor(lod) = L - 1 (weight frac)
            weight = np.where(lo == L, 1.0 - frac, 0.0) + np.where(lo == L - 1, frac, 0.0)
            if not weight.any():
                continue
            hL, wL = levels[L].shape[:2]
            out += weight[..., None] * _bilinear(levels[L], s * wL - 0.5, t * hL - 0.5)
    out = np.where(ok[..., None], out, 0.0)
    return np.clip(np.floor(out + 0.5), 0, 255).astype(np.uint8)
