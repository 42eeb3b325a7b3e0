"""Where the residual report compares, and how it aligns the prediction with the observation.

Per plane, the watched pixels are those the camera sees, ``margin`` projector px inside the
frame and the plane (content moved across a fold or the frame's edge would read as a change).
The content's shift on a plane is found by phase correlation (whole pixels), then refined by
Gauss-Newton on the shift, a gain and an offset (sub-pixel). The focus indicator reads the
band-pass (difference of Gaussians) energies of the observation and of the prediction.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import fft as sfft

__all__ = ["PlaneWindow", "band_energies", "coarse_shift", "downsample_mask",
           "plane_shift", "watched_planes"]


def watched_planes(plane: np.ndarray, n_planes: int, seen: np.ndarray,
                   margin: int) -> list[np.ndarray]:
    """Per plane, the pixels to compare: seen, ``margin`` px inside the frame and the plane.

    Parameters
    ----------
    plane : (Hp, Wp) int plane index of every projector pixel.
    n_planes : int
    seen : (Hp, Wp) bool, where the camera sees the projector pixel.
    margin : int >= 1

    Returns
    -------
    list of (Hp, Wp) bool, one per plane.
    """
    kernel = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    out = []
    for p in range(n_planes):
        inside = np.zeros(plane.shape, np.uint8)
        inside[margin:-margin, margin:-margin] = plane[margin:-margin, margin:-margin] == p
        out.append(cv2.erode(inside, kernel).astype(bool) & seen)
    return out


@dataclass(frozen=True)
class PlaneWindow:
    """One plane's watched pixels cut to their bounding box, with the phase correlation's
    window: what :func:`plane_shift` needs that does not change between reports.

    Attributes
    ----------
    box : (y0, y1, x0, x1), exclusive ends, in projector pixels.
    mask : (y1 - y0, x1 - x0) bool, the watched pixels inside the box.
    flat : int64, the mask's flat indices in the box (gathers are cheaper than boolean masks).
    window : same shape as ``mask``, float64, a Hann window times the mask.
    """

    box: tuple[int, int, int, int]
    mask: np.ndarray
    flat: np.ndarray
    window: np.ndarray

    @classmethod
    def of(cls, mask: np.ndarray) -> PlaneWindow:
        """The window of a non-empty (Hp, Wp) bool mask."""
        ys, xs = np.nonzero(mask)
        y0, y1, x0, x1 = int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1
        m = np.ascontiguousarray(mask[y0:y1, x0:x1])
        return cls((y0, y1, x0, x1), m, np.flatnonzero(m),
                   np.outer(np.hanning(y1 - y0), np.hanning(x1 - x0)) * m)

    @property
    def size(self) -> int:
        """Number of watched pixels."""
        return int(self.flat.size)

    def cut(self, img: np.ndarray) -> np.ndarray:
        """The box of an (Hp, Wp[, C]) image (a view)."""
        y0, y1, x0, x1 = self.box
        return img[y0:y1, x0:x1]


def coarse_shift(a: np.ndarray, b: np.ndarray, m: np.ndarray,
                 window: np.ndarray | None = None) -> tuple[np.ndarray, float]:
    """Whole-pixel (dx, dy) of ``b`` against ``a`` inside ``m`` by phase correlation, and its
    peak (0..1). The whitening is regularised: blurred content has no energy at high
    frequencies, and whitening them fully would only amplify the noise there.

    ``window``: the Hann window times ``m`` (:class:`PlaneWindow`), computed when omitted.
    """
    h, w = a.shape
    win = np.outer(np.hanning(h), np.hanning(w)) * m if window is None else window
    # Zero-padded to sizes the FFT factors well: a box side is often a prime (251 px), where
    # the FFT costs several times more; the window takes both signals to 0 at the box's edge.
    # In float32: half the float64 transforms' time, the same peak to 6 digits.
    s = (sfft.next_fast_len(h, real=True), sfft.next_fast_len(w, real=True))
    fa = sfft.rfft2(((a - a[m].mean()) * win).astype(np.float32), s=s)
    fb = sfft.rfft2(((b - b[m].mean()) * win).astype(np.float32), s=s)
    cross = np.conj(fa) * fb
    mag = np.abs(cross)
    corr = sfft.irfft2(cross / (mag + np.float32(1e-3) * mag.max() + np.float32(1e-30)), s=s)
    py, px = np.unravel_index(int(np.argmax(corr)), corr.shape)
    hh, ww = s
    d = np.array([px - ww if px > ww / 2 else px, py - hh if py > hh / 2 else py], np.float64)
    return d, float(corr[py, px])


def plane_shift(pred: np.ndarray, obs: np.ndarray, win: PlaneWindow, iterations: int = 6,
                start: np.ndarray | None = None, tol: float = 1e-3) -> tuple[np.ndarray, float]:
    """(dx, dy) such that ``obs(x) ≈ gain · pred(x − d) + offset`` inside the plane's window
    (grey (Hp, Wp) images), and the phase correlation peak of the whole-pixel start.

    ``start``: a shift to refine instead of the phase correlation's (the peak is then NaN).
    ``tol``: the Gauss-Newton step (px) below which it stops.
    """
    m, flat = win.mask, win.flat
    a = np.ascontiguousarray(win.cut(pred), np.float32)
    b_box = win.cut(obs)
    b = np.ascontiguousarray(b_box).reshape(-1).take(flat).astype(np.float64)
    if start is None:
        d, peak = coarse_shift(a, np.asarray(b_box, np.float64), m, win.window)
    else:
        d, peak = np.array(start, np.float64), float("nan")
    A = np.empty((4, flat.size))
    A[1] = 1.0
    # Gauss-Newton on the shift, gain and offset: pred(x − d − δ) ≈ W − ∇W · δ, solved by
    # its 4 x 4 normal equations (well conditioned in float64; a QR of the n x 4 system costs
    # as much as the rest of the report).
    for _ in range(iterations):
        M = np.float32([[1, 0, d[0]], [0, 1, d[1]]])
        W = cv2.warpAffine(a, M, (a.shape[1], a.shape[0]), flags=cv2.INTER_CUBIC,
                           borderMode=cv2.BORDER_REPLICATE)
        gy, gx = np.gradient(W)
        A[0] = W.reshape(-1).take(flat)
        A[2] = gx.reshape(-1).take(flat)
        A[3] = gy.reshape(-1).take(flat)
        A[2:] *= -1.0
        (gain, _, u, v), *_ = np.linalg.lstsq(A @ A.T, A @ b, rcond=None)
        if abs(gain) < 1e-6:
            break
        step = np.array([u, v]) / gain
        d += np.clip(step, -2.0, 2.0)
        if np.abs(step).max() < tol:
            break
    return d, peak


def downsample_mask(mask: np.ndarray) -> np.ndarray:
    """A bool mask at the next pyramid level (``cv2.pyrDown``'s grid: pixel i at 2i): the
    pixels whose 3x3 neighbourhood at the finer level is all in the mask."""
    inside = cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8),
                       borderType=cv2.BORDER_CONSTANT, borderValue=0)
    return inside[::2, ::2].astype(bool)


def band_energies(pred: np.ndarray, obs: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """Mean square of the difference of Gaussians (σ 1 and 2 px) of ``pred`` and of ``obs``,
    on the pixels of ``mask`` (a bool image, or the flat indices of its pixels)."""
    flat = np.flatnonzero(mask) if mask.dtype == bool else mask

    def energy(x):
        x = np.asarray(x, np.float32)
        b = cv2.GaussianBlur(x, (0, 0), 1.0)
        cv2.subtract(b, cv2.GaussianBlur(x, (0, 0), 2.0), dst=b)
        b = b.reshape(-1).take(flat)
        return float(np.dot(b, b)) / max(b.size, 1)

    return energy(pred), energy(obs)
