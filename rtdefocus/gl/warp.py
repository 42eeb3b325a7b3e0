"""The warp + stitch pass on the GPU (moderngl): input image -> projector frame.

The fragment shader ``kernels/warp.glsl`` implements docs/internals.md ("The warp") per
projector pixel; :func:`rtdefocus.reference.warp.warp_cv2` is its plain twin and the module
docstring there fixes the sampling rule (bilinear; trilinear on CPU-built mip levels where the
input is minified; black outside). :class:`GLWarp` keeps its program, texture, sampler and
framebuffer across frames: a video of constant size and geometry allocates nothing per frame.
"""

from __future__ import annotations

import logging

import numpy as np

from ..checks import check_choice
from ..errors import DeviceError, InputError, InputTypeError
from ..planar import MAX_PLANES
from ..reference.warp import (
    check_image,
    check_offset,
    check_warp_inputs,
    mip_levels_needed,
    mip_pyramid,
    warp_cv2,
    warp_lod,
)
from .runtime import create_context, load_program, read_rgb

log = logging.getLogger(__name__)

__all__ = ["GLWarp", "shared_renderbuffer", "warp_image"]

# Level-of-detail check on every LOD_STEP-th projector row/column (and the last): enough to
# decide whether the frame minifies anywhere; the LOD itself is computed per pixel in the shader.
LOD_STEP = 4


def st_from_frag_matrices(H: np.ndarray, rect: np.ndarray, projector_size) -> np.ndarray:
    """(n, 3, 3) float64 maps from ``gl_FragCoord`` (fx, fy, 1) to homogeneous texture coordinates.

    ``A @ H[p] @ B``: B takes the fragment centre to the projector pixel (x, y) =
    (fx − 0.5, Hp − 0.5 − fy) (GL counts rows from the bottom), H[p] to the camera, and A to the
    normalised coordinate s = (xc − x0 + 0.5)/w (= (u + 0.5)/W, texel centres at (i + 0.5)/W).
    ``H`` must be sign-normalised (``check_warp_inputs``) so the homogeneous z stays positive.
    """
    x0, y0, w, h = rect
    hp = projector_size[1]
    B = np.array([[1.0, 0.0, -0.5], [0.0, -1.0, hp - 0.5], [0.0, 0.0, 1.0]])
    A = np.array([[1.0 / w, 0.0, (0.5 - x0) / w], [0.0, 1.0 / h, (0.5 - y0) / h], [0.0, 0.0, 1.0]])
    M = A @ H @ B
    # Unit scale per plane keeps float32 well inside its range; z keeps its (positive) sign.
    return M / np.linalg.norm(M, axis=(1, 2), keepdims=True)


class GLWarp:
    """Warp + stitch images into projector space with OpenGL.

    Parameters
    ----------
    ctx : moderngl.Context
        An OpenGL 3.3 context: the EGL offscreen one (:func:`rtdefocus.gl.runtime.create_context`)
        or a projector window's.
    projector_size : (int, int)
        (Wp, Hp) of the frames produced.

    Notes
    -----
    The texture is reallocated only when the input size (or the number of mip levels) changes,
    the geometry uniforms only when the homographies, fold, rect or input size change, and the
    offscreen framebuffer of :meth:`render` is created once.
    """

    def __init__(self, ctx, projector_size: tuple[int, int]):
        import moderngl

        try:
            wp, hp = (int(v) for v in projector_size)
        except (TypeError, ValueError):
            raise InputError(f"projector_size must be (width, height); got {projector_size!r}") from None
        if wp <= 0 or hp <= 0:
            raise InputError(f"projector_size must be positive (width, height); got {projector_size}")
        self.projector_size = (wp, hp)
        self.ctx = ctx
        self.program = load_program(ctx, "warp.glsl", {"MAX_PLANES": MAX_PLANES})
        self.vao = ctx.vertex_array(self.program, [])
        # CLAMP_TO_BORDER with a black border = cv2's BORDER_CONSTANT 0, on every mip level.
        self.sampler = ctx.sampler(repeat_x=False, repeat_y=False, border_color=(0.0, 0.0, 0.0, 0.0),
                                   filter=(moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR))
        self.program["u_image"].value = 0
        self.program["u_labels"].value = 1
        # The plane of every projector pixel, rows bottom-up as GL counts them (R8UI).
        self.labels = ctx.texture((wp, hp), 1, dtype="u1", alignment=1)
        self.labels.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.program["u_offset"].value = 2
        # Each pixel's residual in (s, t) units, rows bottom-up (zeros: the homographies alone).
        self.offset = ctx.texture((wp, hp), 2, dtype="f4")
        self.offset.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.offset.write(np.zeros((hp, wp, 2), np.float32))
        self.texture = None
        self.fbo = None
        self.n_levels = 0
        self._key = None
        self._levels_wanted = 1

    # ------------------------------------------------------------------ state
    def _configure(self, H_cam_from_proj, planes, rect, input_size, offset=None) -> None:
        H, layout, r, psize = check_warp_inputs(H_cam_from_proj, planes, rect,
                                                self.projector_size)
        offset = check_offset(offset, psize)
        M = np.zeros((MAX_PLANES, 3, 3))
        M[:layout.n_planes] = st_from_frag_matrices(H, r, psize)
        # GLSL mat3 is column-major: upload each matrix transposed.
        self.program["u_st_from_frag"].write(np.ascontiguousarray(M.transpose(0, 2, 1), dtype="f4"))
        wp, hp = psize
        ys, xs = np.mgrid[0:hp, 0:wp]
        labels = layout.label(xs.astype(np.float64), ys.astype(np.float64)).astype(np.uint8)
        self.labels.write(np.ascontiguousarray(labels[::-1]), alignment=1)
        st_off = np.zeros((hp, wp, 2), np.float32)
        if offset is not None:
            # The reference adds the float32 offset in camera px; the same value, scaled to s, t.
            st_off = (offset.astype(np.float64) / [r[2], r[3]]).astype(np.float32)
        self.offset.write(np.ascontiguousarray(st_off[::-1]))
        self.program["u_image_size"].value = tuple(float(v) for v in input_size)
        lod = warp_lod(H, layout, r, input_size, psize, step=LOD_STEP)
        max_lod = float(np.nanmax(lod)) if np.isfinite(lod).any() else 0.0
        self._levels_wanted = mip_levels_needed(max_lod, input_size)
        log.debug("warp configured: input %s, rect %s, max lod %.3f, %d mip level(s)",
                  input_size, r.tolist(), max_lod, self._levels_wanted)

    def _upload(self, image: np.ndarray) -> None:
        h, w = image.shape[:2]
        if self.texture is None or self.texture.size != (w, h):
            if self.texture is not None:
                self.texture.release()
            self.texture = self.ctx.texture((w, h), 3, dtype="f1", alignment=1)
            self.n_levels = 0
        if self.n_levels != self._levels_wanted:
            # Allocates levels 1..n-1 (their content is replaced below) and sets MAX_LEVEL,
            # which makes the texture complete for the mipmapping sampler.
            self.texture.build_mipmaps(0, self._levels_wanted - 1)
            self.n_levels = self._levels_wanted
        # Own mip levels (same as the reference's), not glGenerateMipmap: drivers filter odd
        # sizes differently, and these must match warp_cv2 exactly.
        for level, data in enumerate(mip_pyramid(image, self.n_levels)):
            self.texture.write(data, level=level, alignment=1)

    # ------------------------------------------------------------------ drawing
    def render_to(self, target, image: np.ndarray, H_cam_from_proj, planes, rect,
                  offset=None) -> None:
        """Draw the warped ``image`` into ``target`` (a moderngl framebuffer of the projector's
        size, e.g. ``ctx.screen`` of a full-screen projector window). Arguments as :meth:`render`."""
        img = check_image(image)
        size = tuple(getattr(target, "size", self.projector_size))
        if size != self.projector_size:
            raise InputError(f"render target is {size[0]}x{size[1]} but this GLWarp renders "
                             f"{self.projector_size[0]}x{self.projector_size[1]} projector frames; "
                             "make the window/framebuffer the projector's size")
        input_size = (img.shape[1], img.shape[0])
        key = (np.asarray(H_cam_from_proj, dtype=np.float64).tobytes(), _planes_key(planes),
               tuple(float(v) for v in np.asarray(rect, dtype=np.float64).reshape(-1)), input_size,
               _offset_key(offset))
        if key != self._key:
            self._key = None          # stays unset if the new geometry is rejected
            self._configure(H_cam_from_proj, planes, rect, input_size, offset)
            self._key = key
        self._upload(img)
        target.use()
        self.ctx.viewport = (0, 0, *self.projector_size)
        self.texture.use(0)
        self.labels.use(1)
        self.offset.use(2)
        self.sampler.use(0)
        self.vao.render(mode=self.ctx.TRIANGLES, vertices=3)
        self.sampler.clear(0)

    def render(self, image: np.ndarray, H_cam_from_proj, planes, rect,
               offset=None) -> np.ndarray:
        """Warp ``image`` into projector space offscreen.

        Parameters
        ----------
        image : (H, W, 3) uint8
            RGB input, any size.
        H_cam_from_proj : (n, 3, 3) float64
            Per-plane homographies, projector pixel -> camera pixel (n = 1 .. MAX_PLANES).
        planes : PlaneLayout, (3,) float64 or None
            The planes (``calib.layout``); for two planes also their fold line
            ``a x + b y + c = 0`` in projector pixels, plane 0 where negative (ignored when
            n = 1).
        rect : (x0, y0, w, h)
            Display rectangle in camera pixels where the input must appear.
        offset : (Hp, Wp, 2) float32, optional
            The planes' smooth residual in camera px (``calib.residual_dense()``, an array the
            caller does not change in place: it is recognised by identity); None: none.

        Returns
        -------
        (Hp, Wp, 3) uint8
            The projector frame in the input's encoding, top row first; black where no input lands.
        """
        if self.fbo is None:
            self.fbo = self.ctx.framebuffer(
                color_attachments=[self.ctx.renderbuffer(self.projector_size, components=4)])
        self.render_to(self.fbo, image, H_cam_from_proj, planes, rect, offset)
        return read_rgb(self.fbo, self.projector_size)

    def release(self) -> None:
        """Free the GL objects (the context itself stays)."""
        for obj in (self.fbo, self.texture, self.labels, self.offset, self.sampler, self.vao,
                    self.program):
            if obj is not None:
                obj.release()
        self.fbo = self.texture = self.labels = self.offset = None


def _offset_key(offset):
    """Identity of a residual array (None: none); a calibration's dense residual is made once
    and not changed, so its identity stands for its content."""
    if offset is None:
        return None
    arr = np.asarray(offset)
    return (id(offset), arr.__array_interface__["data"][0], arr.shape)


def _planes_key(planes):
    """Hashable identity of a plane layout / fold line / None (the geometry cache key)."""
    if planes is None:
        return None
    if hasattr(planes, "fold_planes"):
        return (planes.n_planes, planes.folds.tobytes(), planes.fold_planes.tobytes())
    return np.asarray(planes, dtype=np.float64).tobytes()


# ---------------------------------------------------------------------- convenience
_shared: dict[tuple[int, tuple[int, int]], tuple[object, GLWarp]] = {}
_warned_no_gl = False


def _shared_warp(ctx, projector_size) -> GLWarp:
    key = (id(ctx), tuple(projector_size))
    if key not in _shared or _shared[key][0] is not ctx:
        _shared[key] = (ctx, GLWarp(ctx, projector_size))
    return _shared[key][1]


def shared_renderbuffer(projector_size):
    """The renderbuffer :func:`warp_image` renders into for this projector size in the shared
    GL context (its last frame; None before the first): GL sharing reads it on the device."""
    warp = _shared_warp(create_context(), projector_size)
    return None if warp.fbo is None else warp.fbo.color_attachments[0]


def warp_image(calib, image: np.ndarray, rect=None, backend: str = "auto") -> np.ndarray:
    """Geometry correction of one image with a calibration.

    Parameters
    ----------
    calib : rtdefocus.Calibration
        Supplies the projector size, ``H_cam_from_proj``, ``layout`` and the display rect.
    image : (H, W, 3) uint8
        RGB input, any size.
    rect : (x0, y0, w, h), optional
        Camera-pixel rectangle to show the input in; default ``calib.display_rect((W, H))``.
    backend : {"auto", "gl", "cv2"}
        ``"gl"``: the EGL shader (DeviceError if unavailable); ``"cv2"``: the reference;
        ``"auto"``: GL when an EGL context can be made, else the reference (one warning).

    Returns
    -------
    (Hp, Wp, 3) uint8
        The projector frame.
    """
    global _warned_no_gl
    missing = [a for a in ("projector_size", "H_cam_from_proj", "layout", "display_rect")
               if not hasattr(calib, a)]
    if missing:
        raise InputTypeError(f"warp_image needs an rtdefocus Calibration first; got "
                             f"{type(calib).__name__} (no {', '.join(missing)}). Make one with "
                             "rd.calibrate(procam) or rd.Calibration.load('setup.npz')")
    check_choice(backend, ("auto", "gl", "cv2"), "backend")
    img = check_image(image)
    if rect is None:
        rect = calib.display_rect((img.shape[1], img.shape[0]))
    if backend in ("auto", "gl"):
        try:
            ctx = create_context()
        except DeviceError as exc:
            if backend == "gl":
                raise
            if not _warned_no_gl:
                log.warning("OpenGL unavailable, warping with the (slower) cv2 reference: %s", exc)
                _warned_no_gl = True
            backend = "cv2"
        else:
            backend = "gl"
    if backend == "gl":
        return _shared_warp(ctx, calib.projector_size).render(
            img, calib.H_cam_from_proj, calib.layout, rect, _residual(calib))
    return warp_cv2(img, calib.H_cam_from_proj, calib.layout, rect, calib.projector_size,
                    _residual(calib))


def _residual(calib):
    """The calibration's dense residual (None without one, or for an object without it)."""
    dense = getattr(calib, "residual_dense", None)
    return dense() if dense is not None else None
