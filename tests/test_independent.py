"""Constants checked against values written down from their standards, not against the code's
own inverse: BT.601 YCbCr (the metric's colour space), the reflected binary Gray code (the
geometry stage's stripes) and the radial lens model (OpenCV's distortion formula, computed by
OpenCV)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rtdefocus.calib.geometry.structured_light import LinePatterns
from rtdefocus.graycode import decode_gray
from rtdefocus.planar import distort_points, distortion_scale, undistort_points
from rtdefocus.reference.metric import M_RGB_TO_YCBCR, rgb_to_ycbcr


# --------------------------------------------------------------------------- BT.601 YCbCr
def test_ycbcr_matrix_is_bt601_full_range():
    """ITU-R BT.601 luma weights K_R = 0.299, K_B = 0.114; full-range chroma as in ITU-T T.871
    (JFIF) Table/Eq. 3, without its +128 offset. Rows written from the standard's text."""
    t871 = np.array([[0.299, 0.587, 0.114],
                     [-0.1687, -0.3313, 0.5],
                     [0.5, -0.4187, -0.0813]])
    assert np.abs(M_RGB_TO_YCBCR - t871).max() < 6e-5, M_RGB_TO_YCBCR
    # The same from the definitions Cb = (B - Y) / (2 (1 - K_B)), Cr = (R - Y) / (2 (1 - K_R)).
    kr, kb = 0.299, 0.114
    y = np.array([kr, 1 - kr - kb, kb])
    cb = (np.array([0, 0, 1]) - y) / (2 * (1 - kb))
    cr = (np.array([1, 0, 0]) - y) / (2 * (1 - kr))
    np.testing.assert_allclose(M_RGB_TO_YCBCR, np.stack([y, cb, cr]), atol=1e-6)


@pytest.mark.parametrize("rgb, ycbcr", [
    ((1, 1, 1), (1.0, 0.0, 0.0)),                 # white: full luma, no chroma
    ((1, 0, 0), (0.299, -0.1687, 0.5)),           # T.871: red sits on the Cr axis' end
    ((0, 0, 1), (0.114, 0.5, -0.0813)),           # blue on the Cb axis' end
    ((0, 1, 0), (0.587, -0.3313, -0.4187)),
])
def test_ycbcr_of_primaries(rgb, ycbcr):
    img = np.asarray(rgb, np.float32)[:, None, None] * np.ones((3, 2, 2), np.float32)
    got = rgb_to_ycbcr(img)[:, 0, 0]
    np.testing.assert_allclose(got, ycbcr, atol=6e-5)


# --------------------------------------------------------------------------- Gray code
REFLECTED_BINARY = ["000", "001", "011", "010", "110", "111", "101", "100"]   # Gray, 1953


def test_gray_patterns_carry_the_reflected_binary_code():
    """Stripe k of the vertical patterns lights bit b of the k-th 3-bit Gray code word
    (MSB first), and decoding those words gives back 0..7."""
    lp = LinePatterns((256, 128), spacing=32)
    assert lp.n_bits("v") == 3
    for k, word in enumerate(REFLECTED_BINARY):
        x = 32 * k + 16                                     # a pixel inside stripe k
        bits = "".join("1" if lp.gray_pattern("v", b)[0, x, 0] == 255 else "0" for b in range(3))
        assert bits == word, f"stripe {k}: {bits} != {word}"
        assert lp.gray_pattern("h", 0).shape == (128, 256, 3)
    words = [np.array([[c == "1" for c in w]]).T.reshape(3, 1, 1) for w in REFLECTED_BINARY]
    decoded = [int(decode_gray(list(w))[0, 0]) for w in words]
    assert decoded == list(range(8))


# --------------------------------------------------------------------------- the lens model
def _opencv(pts, k, size):
    """OpenCV's pinhole + radial model: f = half diagonal, principal point the image centre."""
    cx, cy, s = distortion_scale(size)
    K = np.array([[s, 0, cx], [0, s, cy], [0, 0, 1]], np.float64)
    obj = np.column_stack([(pts[:, 0] - cx) / s, (pts[:, 1] - cy) / s, np.ones(len(pts))])
    dist = np.array([k[0], k[1], 0.0, 0.0, 0.0])
    out, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), K, dist)
    return out.reshape(-1, 2), K, dist


@pytest.mark.parametrize("k", [(-0.05, 0.0), (-0.03, -0.05), (0.08, 0.02)])
def test_lens_model_is_opencvs_radial_distortion(k):
    size = (640, 480)
    rng = np.random.default_rng(7)
    pts = np.vstack([rng.uniform((0, 0), size, (200, 2)), [[0, 0], [639, 479], [0, 479]]])
    want, K, dist = _opencv(pts, k, size)
    got = distort_points(pts, k, size)
    assert np.abs(got - want).max() < 1e-6
    back = cv2.undistortPoints(want.reshape(-1, 1, 2), K, dist,
                               criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12))
    back = back.reshape(-1, 2) * K[0, 0] + K[:2, 2]
    assert np.abs(undistort_points(want, k, size) - back).max() < 1e-3


def test_lens_model_by_hand():
    """640x480: centre (319.5, 239.5), r = 1 at 400 px. A point 400 px right of the centre with
    k1 = -0.05, k2 = 0.01 moves to 319.5 + 400 (1 - 0.05 + 0.01) = 703.5."""
    got = distort_points(np.array([[719.5, 239.5], [319.5, 39.5]]), (-0.05, 0.01), (640, 480))
    # second point: r = 0.5, factor 1 - 0.05/4 + 0.01/16 = 0.988125, 200 px up -> 197.625
    np.testing.assert_allclose(got, [[703.5, 239.5], [319.5, 239.5 - 197.625]], atol=1e-9)
