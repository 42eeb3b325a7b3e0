"""The residual report with everything that does not change between reports kept.

:class:`ResidualPredictor` is built once per calibration: the camera→projector resampling
maps and what the camera sees, the watched pixels of each plane and their phase correlation
windows, the albedo and ambient maps, the camera and projector response tables, and the
kernel field, on the OpenCL device (``kernels/blur.cl`` through :class:`~rtdefocus.cl.blur.ClBlur`)
or as the NumPy reference's weight maps. A report then costs one forward blur, one resampling
of the capture and the per-plane alignment. The maths is :mod:`~rtdefocus.watch.residual`'s;
the alignment is :mod:`~rtdefocus.watch.align`.

The device work runs on a queue of its own (a context the watcher shares with no one): a
report taken on a background thread never waits in the show's queue behind its frames, nor
the show's frames behind it (on a CPU device the two still share the cores).
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass

import cv2
import numpy as np

from ..calib.file import Calibration
from ..calib.radiometry.camera_response import linearize
from ..calib.radiometry.stage import projector_to_camera_maps
from ..errors import InputError
from ..reference.blur import blur_forward_filter2d, weight_maps
from .align import PlaneWindow, band_energies, coarse_shift, downsample_mask, plane_shift, watched_planes

log = logging.getLogger(__name__)

__all__ = ["BACKENDS", "ResidualPredictor", "ResidualReport", "calibration_keys",
           "default_margin"]

BACKENDS = ("auto", "opencl", "numpy")

_runtime = None
_runtime_lock = threading.Lock()


@dataclass
class ResidualReport:
    """What one capture says about the calibration (see :func:`~.residual.residual_report`).

    Attributes
    ----------
    gain : camera light observed per unit predicted (1: unchanged exposure and albedo).
    ambient_added : mean camera-linear light added beyond the prediction (0: unchanged room
        light), over the watched pixels.
    shifts_proj : (n_planes, 2) float64, (dx, dy) projector px by which the content seen on
        each plane moved against the prediction (NaN where the plane had too few pixels).
    confidence : (n_planes,) float64, phase correlation peak (0..1); small on plain content.
    band_ratio : band-pass (DoG, σ = 1 and 2 projector px) RMS of the observation over that of
        the prediction, on the watched pixels; it falls when the blur grows.
    rms_before, rms_after : RMS of observed − predicted before, and after, the alignment and
        the light fit (camera-linear light).
    watched : number of projector pixels compared.
    band_rms : the band-pass RMS of the (aligned) prediction on the watched pixels (camera
        linear light): how much fine content the look had to read ``band_ratio`` on.
    """

    gain: float
    ambient_added: float
    shifts_proj: np.ndarray
    confidence: np.ndarray
    band_ratio: float
    rms_before: float
    rms_after: float
    watched: int
    band_rms: float = float("nan")


def default_margin(projector_size: tuple[int, int]) -> int:
    """Projector px kept away from the frame's edge and the folds: 4 % of the smaller side,
    at least 8."""
    return max(8, int(0.04 * min(projector_size)))


# Fields a predictor reads, by the part they build. Small ones are compared by value; per-pixel
# maps by identity and a strided sample of their values (a map replaced or changed in place
# both show).
_KEY_FIELDS = (
    ("H_cam_from_proj", "folds_proj", "fold_planes", "camera_distortion", "residual_cam"),
    ("psfs", "pix_idx", "pix_wts"),
    ("response_lut", "camera_lut", "albedo_proj", "ambient_proj"),
)


def _value_key(a) -> tuple | None:
    if a is None:
        return None
    a = np.asarray(a)
    if a.size <= 1 << 16:
        return a.shape, a.dtype.str, a.tobytes()
    return id(a), a.shape, a.dtype.str, a.reshape(-1)[::997].tobytes()


def calibration_keys(calib: Calibration) -> tuple[tuple, tuple, tuple]:
    """Keys of what a predictor reads from ``calib``: (geometry, kernel field, light). Equal
    keys mean the part built from them can be reused (:class:`ResidualPredictor` ``reuse``)."""
    sizes = (tuple(calib.projector_size), tuple(calib.camera_size))
    return tuple((sizes, *(_value_key(getattr(calib, f)) for f in names))
                 for names in _KEY_FIELDS)


def _watch_runtime():
    """The watcher's own OpenCL context and queue on the chosen device (created on first use)."""
    global _runtime
    from ..cl.runtime import ClRuntime, get_runtime
    with _runtime_lock:
        if _runtime is None:
            _runtime = ClRuntime(get_runtime().device)
        return _runtime


def resolve_backend(backend: str) -> str:
    """"opencl" or "numpy" for a requested backend; "auto" falls back to NumPy with one warning
    per process when no OpenCL device is usable, "opencl" then raises DeviceError."""
    if backend not in BACKENDS:
        raise InputError(f"backend must be one of {BACKENDS}; got {backend!r}")
    from ..cl import runtime as cl_runtime
    return cl_runtime.choose_backend(backend, "the watcher predicts the camera view", log)


def _check_frame(calib: Calibration, frame) -> np.ndarray:
    wp, hp = calib.projector_size
    frame = np.asarray(frame)
    if frame.shape != (hp, wp, 3) or frame.dtype != np.uint8:
        raise InputError(f"the shown frame must be ({hp}, {wp}, 3) uint8 (the projector's size); "
                         f"got {frame.dtype} {frame.shape}")
    return frame


def _check_capture(calib: Calibration, capture) -> np.ndarray:
    wc, hc = calib.camera_size
    capture = np.asarray(capture)
    if capture.shape != (hc, wc, 3):
        raise InputError(f"the capture must be ({hc}, {wc}, 3) (the calibration's camera size); "
                         f"got {capture.shape}")
    return capture


class ResidualPredictor:
    """The calibration's forward model and residual report, prepared once per calibration.

    Parameters
    ----------
    calib : Calibration with geometry (radiometry, kernels and ``camera_lut`` when present).
        The predictor keeps what it needs at construction: a calibration changed afterwards
        needs a new predictor (:func:`~.residual.residual_report` builds one when it sees a
        change).
    backend : "auto" | "opencl" | "numpy"
        Where the forward blur runs; "auto" takes the OpenCL device when there is one.
    margin : projector px kept away from the frame's edge and the folds (None:
        :func:`default_margin`).
    runtime : rtdefocus.cl.ClRuntime, optional
        The OpenCL context and queue to use (default: the watcher's own, on the chosen device).
    level : int >= 0
        Pyramid level (``cv2.pyrDown`` steps) where each plane's shift is found: by phase
        correlation and Gauss-Newton there, then ``refine`` Gauss-Newton steps at full
        resolution. The content on the wall is blurred, so a coarser level loses little of it
        and costs a quarter per level (``tools/bench_watch.py`` compares the shifts).
    refine : int >= 0
        Full-resolution Gauss-Newton steps after the pyramid level (0: the level's shift,
        about 0.05 px further from the true motion on a projector bump, at 85 % of the cost).
    reuse : ResidualPredictor, optional
        A predictor of an earlier state of the calibration: its geometry part (maps, watched
        pixels) and its kernel field (on the device) are taken over where the calibration's
        keys say they are unchanged, so a mend of the light alone rebuilds only the light maps.

    Attributes
    ----------
    backend : "opencl" | "numpy" (resolved)
    margin : int
    keys : the calibration's :func:`calibration_keys` when the predictor was built.
    """

    def __init__(self, calib: Calibration, backend: str = "auto", margin: int | None = None,
                 runtime=None, level: int = 1, refine: int = 1,
                 reuse: ResidualPredictor | None = None):
        self.calib = calib
        self.backend = resolve_backend(backend)
        self.margin = default_margin(calib.projector_size) if margin is None else int(margin)
        if self.margin < 1:
            raise InputError(f"margin must be at least 1 projector px; got {margin}")
        self.level, self.refine = int(level), int(refine)
        if self.level < 0 or self.refine < 0:
            raise InputError(f"level and refine must be >= 0; got {level} and {refine}")
        # The phase correlation's peak (the watcher's confidence) falls as the frame grows:
        # the blur widens with it, and whitening spreads the peak over more noisy high
        # frequencies. It is read where the frame is nearest 400 px wide (the size its
        # threshold was measured at), at most the pyramid level.
        wide = calib.projector_size[0]
        self.peak_level = (self.level if self.level and wide >= 400 * 2 ** (self.level - 0.5)
                           else 0)
        self.keys = calibration_keys(calib)
        same = [reuse is not None and reuse.keys[i] == self.keys[i] for i in range(2)]
        if same[0] and (reuse.margin, reuse.level) == (self.margin, self.level):
            for name in self._GEOMETRY:
                setattr(self, name, getattr(reuse, name))
        else:
            self._setup_geometry(calib)
        self._lock = threading.Lock()
        self._blur = None
        if same[1] and reuse.backend == self.backend and runtime is None:
            # the kernel field (on the device) and its buffers, with the lock that guards them
            for name in ("_blur", "_wmaps", "_queue", "_src", "_dst", "_lock"):
                if hasattr(reuse, name):
                    setattr(self, name, getattr(reuse, name))
        elif calib.has_psf:
            if self.backend == "opencl":
                self._setup_cl(runtime)
            else:
                self._wmaps = weight_maps(calib.pix_idx, calib.pix_wts)
        self._setup_light(calib)

    #: What :meth:`_setup_geometry` computes (kept by a predictor that ``reuse``s it).
    _GEOMETRY = ("_maps", "seen", "masks", "windows", "coarse_windows", "watched", "_wflat",
                 "_band_box", "_band_flat")

    def _setup_geometry(self, calib: Calibration) -> None:
        """Camera→projector maps, what the camera sees, the watched pixels and windows."""
        wp, hp = calib.projector_size
        self._maps = projector_to_camera_maps(calib)
        wc, hc = calib.camera_size
        mx, my = self._maps
        self.seen = (mx >= 0) & (mx <= wc - 1) & (my >= 0) & (my <= hc - 1)
        masks = watched_planes(calib.plane_map(), calib.n_planes, self.seen, self.margin)
        self.masks = masks
        self.windows = [PlaneWindow.of(m) if m.any() else None for m in masks]
        coarse = []
        for m in masks:
            for _ in range(self.level):
                m = downsample_mask(m)
            coarse.append(PlaneWindow.of(m) if m.sum() >= 16 else None)
        self.coarse_windows = coarse
        self.watched = np.any(masks, axis=0) if masks else np.zeros((hp, wp), bool)
        self._wflat = np.flatnonzero(self.watched)
        # The band-pass energy is read on the watched pixels' box widened by the DoG's reach
        # (OpenCV's σ = 2 kernel: 8 px), the same values as on the whole frame.
        if self._wflat.size:
            ys, xs = np.nonzero(self.watched)
            y0, y1 = max(0, ys.min() - 8), min(hp, ys.max() + 9)
            x0, x1 = max(0, xs.min() - 8), min(wp, xs.max() + 9)
        else:
            y0, y1, x0, x1 = 0, hp, 0, wp
        self._band_box = (slice(y0, y1), slice(x0, x1))
        self._band_flat = np.flatnonzero(self.watched[self._band_box])

    def _setup_light(self, calib: Calibration) -> None:
        """Response tables, albedo and ambient maps as the report uses them."""
        wp, hp = calib.projector_size
        self._lut = np.ascontiguousarray(calib.lut, np.float32)
        self._lut3 = [np.ascontiguousarray(t[None]) for t in self._lut]     # cv2.LUT's (1, 256)
        cam = calib.camera_lut
        # uint8 captures read the inverse response by table (np.interp at whole codes is the
        # table itself); other captures (averaged frames) go through linearize.
        self._cam_table = (None if cam is None or np.isscalar(cam) else
                           np.ascontiguousarray(np.asarray(cam, np.float32).T[None]))
        self._albedo = (None if calib.albedo_proj is None
                        else np.ascontiguousarray(calib.albedo_proj, np.float32))
        self._ambient = (None if calib.ambient_proj is None
                         else np.ascontiguousarray(calib.ambient_proj, np.float32))
        self._inv_albedo = (None if self._albedo is None
                            else 1.0 / np.maximum(self._albedo, np.float32(1e-3)))
        # Planar thirds of the light maps: the report works on grey (channel-mean) images.
        third = np.float32(1.0 / 3.0)
        self._alb3 = (None if self._albedo is None
                      else np.ascontiguousarray(self._albedo.transpose(2, 0, 1)) * third)
        self._ia3 = None if self._inv_albedo is None else self._inv_albedo * third
        self._third = np.full((1, 3), third, np.float32)        # cv2.transform: channel mean
        self._one = np.ones((1, 3), np.float32)                 # cv2.transform: channel sum
        self._amb_g = None if self._ambient is None else self._ambient.mean(axis=2)
        # the ambient as it reads in the content (ambient / albedo, grey)
        self._amb_content_g = (None if self._ambient is None else
                               (self._ambient * (1.0 if self._inv_albedo is None
                                                 else self._inv_albedo)).mean(axis=2))
        if self._ambient is not None and self.watched.any() and \
                float(self._ambient[self.watched].mean()) > 1e-6:
            shape = self._ambient.mean(axis=2)
            self._shape = shape / shape[self.watched].mean()
        else:
            self._shape = np.ones((hp, wp), np.float32)
        self._shape_w = self._shape.reshape(-1)[self._wflat].astype(np.float32)
        self._shape_ss = float(np.dot(self._shape_w.astype(np.float64), self._shape_w))

    def _setup_cl(self, runtime) -> None:
        import pyopencl.array as cla

        from ..cl.blur import ClBlur
        rt = runtime if runtime is not None else _watch_runtime()
        calib = self.calib
        self._blur = ClBlur(rt, calib.psfs, calib.pix_idx, calib.pix_wts, channels=3)
        self._queue = rt.queue
        self._src = cla.empty(rt.queue, self._blur.shape, np.float32)
        self._dst = cla.empty(rt.queue, self._blur.shape, np.float32)

    # ------------------------------------------------------------------ forward model
    def blurred_planar(self, frame: np.ndarray) -> np.ndarray:
        """``F P``: the frame in linear light, blurred by the calibrated kernels, planar
        (3, Hp, Wp) float32 (the identity blur without kernels)."""
        frame = _check_frame(self.calib, frame)
        lin = np.empty((3, *frame.shape[:2]), np.float32)
        # decode_lut's table look-up (no headroom), by plane (cv2.LUT: a tenth of np.take's
        # time on uint8 codes, the same values)
        for c, codes in enumerate(cv2.split(frame)):
            cv2.LUT(codes, self._lut3[c], dst=lin[c])
        if self._blur is not None:
            with self._lock:
                self._src.set(lin, queue=self._queue)
                self._blur.forward(self._src, self._dst)
                lin = self._dst.get(queue=self._queue)
        elif self.calib.has_psf:
            c = self.calib
            lin = blur_forward_filter2d(lin, c.psfs, c.pix_idx, c.pix_wts, maps=self._wmaps)
        return lin

    def blurred(self, frame: np.ndarray) -> np.ndarray:
        """:meth:`blurred_planar` as an (Hp, Wp, 3) float32 image."""
        return np.ascontiguousarray(self.blurred_planar(frame).transpose(1, 2, 0))

    def with_light(self, blurred: np.ndarray) -> np.ndarray:
        """albedo · blurred + ambient, with what the calibration knows of them, (Hp, Wp, 3)."""
        out = blurred * self._albedo if self._albedo is not None else blurred.copy()
        if self._ambient is not None:
            out += self._ambient
        return out

    def predict(self, frame: np.ndarray) -> np.ndarray:
        """The camera's linear light expected at each projector pixel, (Hp, Wp, 3) float32."""
        return self.with_light(self.blurred(frame))

    def observe(self, capture: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A camera frame as linear light at each projector pixel (0 where unseen), (Hp, Wp, 3)
        float32, and where the camera sees it, (Hp, Wp) bool."""
        capture = _check_capture(self.calib, capture)
        if capture.dtype == np.uint8 and self._cam_table is not None:
            lin = cv2.LUT(np.ascontiguousarray(capture), self._cam_table)
        else:
            lin = linearize(capture, self.calib.camera_lut)
        out = cv2.remap(np.ascontiguousarray(lin, dtype=np.float32), *self._maps,
                        interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                        borderValue=0)
        return out, self.seen

    # ------------------------------------------------------------------ the report
    def report(self, frame: np.ndarray, capture: np.ndarray,
               min_pixels: int = 400) -> ResidualReport:
        """Compare a capture with the prediction of it: light, geometry and focus (see
        :func:`~.residual.residual_report`, whose parameters and result these are)."""
        calib = self.calib
        frame = _check_frame(calib, frame)
        capture = _check_capture(calib, capture)
        n = int(self._wflat.size)
        if n < min_pixels:
            raise InputError(f"the camera sees only {n} projector pixels of this calibration; "
                             "check that the capture and the calibration belong to the same "
                             "set-up")
        blurred = self.blurred_planar(frame)                                # (3, Hp, Wp)
        blurred_g = blurred[0] + blurred[1]
        blurred_g += blurred[2]
        blurred_g *= np.float32(1.0 / 3.0)
        pred_g = self._light_g(blurred, blurred_g)
        obs, _ = self.observe(capture)
        obs_g = cv2.transform(obs, self._third)
        # The content alone, as the projector put it on the wall: room light off, / albedo.
        if self._ia3 is not None:
            content_g = cv2.transform(cv2.multiply(obs, self._ia3), self._one)
        else:
            content_g = obs_g.copy()
        if self._amb_content_g is not None:
            content_g -= self._amb_content_g
        shifts = np.full((calib.n_planes, 2), np.nan)
        conf = np.zeros(calib.n_planes)
        aligned = pred_g.copy()
        pyr = [(blurred_g, content_g)]
        for _ in range(self.level):
            pyr.append((cv2.pyrDown(pyr[-1][0]), cv2.pyrDown(pyr[-1][1])))
        for p, win in enumerate(self.windows):
            if win is None or win.size < min_pixels:
                continue
            shifts[p], conf[p] = self._shift(pyr, win, self.coarse_windows[p])
            # The prediction with the content moved as it did, for the light fit.
            self._moved_into(aligned, blurred, shifts[p], win)
        w = self._wflat
        a, y = aligned.reshape(-1).take(w), obs_g.reshape(-1).take(w)
        sh = self._shape_w
        # the 2 x 2 normal equations of y ≈ gain · a + added · shape, summed in float64
        A = np.array([[np.dot(a, a), np.dot(a, sh)], [np.dot(a, sh), self._shape_ss]], np.float64)
        (gain, added), *_ = np.linalg.lstsq(A, [np.dot(a, y), np.dot(sh, y)], rcond=None)
        before = y - pred_g.reshape(-1).take(w)
        after = y - np.float32(gain) * a - np.float32(added) * sh
        e_pred, e_obs = band_energies(aligned[self._band_box], obs_g[self._band_box],
                                      self._band_flat)
        return ResidualReport(gain=float(gain), ambient_added=float(added), shifts_proj=shifts,
                              confidence=conf,
                              band_ratio=(float(np.sqrt(e_obs / e_pred)) if e_pred > 0
                                          else float("nan")),
                              rms_before=float(np.sqrt(np.dot(before, before) / before.size)),
                              rms_after=float(np.sqrt(np.dot(after, after) / after.size)),
                              watched=n, band_rms=float(np.sqrt(e_pred)))

    def _shift(self, pyr: list, win: PlaneWindow, coarse: PlaneWindow | None
               ) -> tuple[np.ndarray, float]:
        """A plane's shift: the whole-pixel start and its peak by phase correlation at full
        resolution (the peak is the watcher's confidence, so it is read where the content
        is), Gauss-Newton at the pyramid level, then ``refine`` steps at full resolution."""
        fine_pred, fine_obs = pyr[0]
        if coarse is None or self.level == 0:
            return plane_shift(fine_pred, fine_obs, win)
        scale = 2.0 ** self.level
        if self.peak_level:
            (lp, lo), w = pyr[-1], coarse
            start, peak = coarse_shift(w.cut(lp), np.asarray(w.cut(lo), np.float64), w.mask,
                                       w.window)
        else:
            start, peak = coarse_shift(win.cut(fine_pred), np.asarray(win.cut(fine_obs),
                                       np.float64), win.mask, win.window)
            start = start / scale
        # A hundredth of a level pixel: the full-resolution step that follows corrects more.
        d, _ = plane_shift(pyr[-1][0], pyr[-1][1], coarse, start=start, tol=0.01)
        d *= scale
        if self.refine:
            d, _ = plane_shift(fine_pred, fine_obs, win, iterations=self.refine, start=d)
        return d, peak

    def _light_g(self, blurred: np.ndarray, blurred_g: np.ndarray,
                 box: tuple[slice, slice] = (slice(None), slice(None))) -> np.ndarray:
        """Grey albedo · blurred + ambient of planar ``blurred`` (``blurred_g`` its grey),
        both cut to ``box`` (rows, columns) of the frame."""
        if self._alb3 is not None:
            a = self._alb3[(slice(None), *box)]
            out = blurred[0] * a[0]
            for c in (1, 2):
                out += blurred[c] * a[c]
        else:
            out = blurred_g.copy()
        if self._amb_g is not None:
            out += self._amb_g[box]
        return out

    def _moved_into(self, aligned: np.ndarray, blurred: np.ndarray, d: np.ndarray,
                    win: PlaneWindow) -> None:
        """Write the grey prediction of planar ``blurred`` moved by ``d`` into ``aligned`` on
        the plane's watched pixels. Only the plane's box, widened by the shift, is warped: the
        same values as warping the whole frame (bilinear reads 2x2 neighbours; the frame's
        own border is replicated either way)."""
        hp, wp = aligned.shape
        y0, y1, x0, x1 = win.box
        pad = int(np.ceil(np.abs(d).max())) + 2
        ya, yb, xa, xb = max(0, y0 - pad), min(hp, y1 + pad), max(0, x0 - pad), min(wp, x1 + pad)
        M = np.float32([[1, 0, d[0]], [0, 1, d[1]]])
        inner = (slice(y0 - ya, y1 - ya), slice(x0 - xa, x1 - xa))
        moved = np.stack([
            cv2.warpAffine(np.ascontiguousarray(blurred[c, ya:yb, xa:xb]), M, (xb - xa, yb - ya),
                           flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)[inner]
            for c in range(3)])
        moved_g = self._light_g(moved, moved.mean(axis=0), (slice(y0, y1), slice(x0, x1)))
        box = aligned[y0:y1, x0:x1]
        box[win.mask] = moved_g[win.mask]
