"""An independent reference for the compensation solve: the box-constrained
minimum of Eq. 4 on the simulator's true kernels, by plain projected gradient with exact line
search run to convergence, written from DESIGN.md §3 with SciPy sparse matrices only — it
shares no code with ``rtdefocus.compensate``, ``rtdefocus.reference`` or ``rtdefocus.cl``
(only the BT.601 matrix and the default weights, which are constants of the method).

F is built from the simulator's ground truth through ``oracle_calibration`` (the renderer's own
kernels, equal to its blur to float precision; tests/test_sim.py holds that against the
renderer). The yardstick is what the best possible solve on perfect kernels reaches, so a
regression of the production solver (fewer iterations, a wrong step) shows against it.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

BT601 = np.array([[0.299, 0.587, 0.114],
                  [-0.168736, -0.331264, 0.5],
                  [0.5, -0.418688, -0.081312]])
WEIGHTS = (1.0, 0.5, 0.25, 0.0)     # Eq. 4 (w1, w2, w3, w4): rtdefocus's DEFAULT_WEIGHTS


def kernel_matrix(psfs, idx, wts) -> sp.csr_matrix:
    """F as an (N, N) sparse matrix, N = Hp·Wp, row x = the gather kernel k_x:
    ``O(x) = sum_u k_x(u) P(x - u)`` with ``psf[k//2 + v, k//2 + u] = k(u, v)``; P outside
    the frame is 0."""
    hp, wp = idx.shape[:2]
    k = psfs.shape[1]
    r = k // 2
    K = np.einsum("hwj,hwjab->hwab", wts.astype(np.float64), psfs[idx].astype(np.float64))
    yy, xx = np.mgrid[0:hp, 0:wp]
    rows, cols, vals = [], [], []
    for v in range(-r, r + 1):
        for u in range(-r, r + 1):
            val = K[:, :, r + v, r + u]
            ys, xs = yy - v, xx - u
            ok = (val != 0) & (ys >= 0) & (ys < hp) & (xs >= 0) & (xs < wp)
            rows.append((yy * wp + xx)[ok])
            cols.append((ys * wp + xs)[ok])
            vals.append(val[ok])
    n = hp * wp
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                         shape=(n, n))


def laplacian_matrix(hp: int, wp: int) -> sp.csr_matrix:
    """∇ᵀ∇ with 4-connected forward differences (Neumann border), (N, N)."""
    def diff(n):
        return sp.diags([-np.ones(n - 1), np.ones(n - 1)], [0, 1], shape=(n - 1, n))
    Dx = sp.kron(sp.identity(hp), diff(wp))
    Dy = sp.kron(diff(hp), sp.identity(wp))
    return (Dx.T @ Dx + Dy.T @ Dy).tocsr()


class ReferenceSolve:
    """min over 0 <= P <= 1 of d(P) = Σ_c w_c ‖(M e)_c‖² + s_c ‖∇(M e)_c‖², e = F P − I.

    P, I are (N, 3) (pixels × RGB)."""

    def __init__(self, psfs, idx, wts, weights=WEIGHTS):
        hp, wp = idx.shape[:2]
        self.shape = (hp, wp)
        self.F = kernel_matrix(psfs, idx, wts)
        self.FT = self.F.T.tocsr()
        self.L = laplacian_matrix(hp, wp)
        self.w = np.array([weights[0], weights[1], weights[1]])
        self.s = np.array([weights[2], weights[3], weights[3]])

    def Q(self, e):
        """The metric's field: Mᵀ (w ⊙ Me + s ⊙ L Me), so that d = <e, Q e>."""
        y = e @ BT601.T
        return (y * self.w + (self.L @ y) * self.s) @ BT601

    def solve(self, target, iterations=400, rtol=1e-6):
        """Projected gradient with exact line search from P = I; stops when a step lowers d
        by less than ``rtol`` of d(start). Returns (P, distances)."""
        I = target.astype(np.float64)
        P = np.clip(I, 0.0, 1.0)
        e = self.F @ P - I
        Qe = self.Q(e)
        d = [float(np.sum(e * Qe))]
        for _ in range(iterations):
            g = 2.0 * (self.FT @ Qe)
            step = -g
            step[((P <= 0) & (step < 0)) | ((P >= 1) & (step > 0))] = 0.0
            Fs = self.F @ step
            curv = float(np.sum(Fs * self.Q(Fs)))
            if curv <= 0:
                break
            t = -float(np.sum(g * step)) / (2.0 * curv)
            Pn = np.clip(P + t * step, 0.0, 1.0)
            D = Pn - P                                  # the chord to the clamped point
            FD = self.F @ D
            QFD = self.Q(FD)
            a, b = float(np.sum(FD * QFD)), float(np.sum(g * D))
            tau = 1.0 if a <= 0 else min(1.0, max(0.0, -b / (2.0 * a)))
            P = P + tau * D
            e = e + tau * FD
            Qe = Qe + tau * QFD
            d.append(float(np.sum(e * Qe)))
            if d[-2] - d[-1] < rtol * d[0]:
                break
        return P, d

    def compensate(self, calib_lut_gamma: float, warped: np.ndarray, **kw):
        """uint8 (Hp, Wp, 3) geometry-corrected frame -> uint8 projector frame, through the
        simulator's own response ``(v/255)^gamma``."""
        hp, wp = self.shape
        target = (warped.reshape(-1, 3).astype(np.float64) / 255.0) ** calib_lut_gamma
        P, d = self.solve(target, **kw)
        out = np.rint(255.0 * np.clip(P, 0, 1) ** (1.0 / calib_lut_gamma))
        return out.reshape(hp, wp, 3).astype(np.uint8), d
