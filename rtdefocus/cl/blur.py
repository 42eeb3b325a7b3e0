"""The spatially varying blur F and its exact adjoint on an OpenCL device (``kernels/blur.cl``).

The kernel field (``psfs``, ``idx``, ``wts``; docs/internals.md "Kernel field F") is uploaded
once; :meth:`ClBlur.forward` and :meth:`ClBlur.adjoint` then only enqueue a kernel on planar
``(C, H, W)`` float32 device arrays. NumPy twin: :mod:`rtdefocus.reference.blur`.

Two variants of the same maths, chosen when the program is built:

``"gpu"``  one work-item per pixel, the tile plus halo in local memory;
``"cpu"``  one work-item per 16-pixel row chunk (forward) or a 16-pixel column of
           :data:`ROWS_COL` rows (adjoint) with explicit ``float16`` vectors, blending the taps
           of the few PSFs active there (the shape a CPU's SIMD units want).

For the CPU shape the host lists, once, the distinct PSFs of every chunk with their weights
(:func:`chunk_groups`) and, for the adjoint, the PSFs within reach of every column block
(:func:`pixel_members`, :func:`block_groups`); ``kernels/blur.cl`` documents the layouts.
"""

from __future__ import annotations

import logging

import numpy as np

from ..errors import DeviceError, InputError
from ..reference.blur import check_field, psf_support

log = logging.getLogger(__name__)

__all__ = ["ClBlur", "block_groups", "chunk_groups", "group_row_extents", "pixel_members",
           "row_extents"]

CHUNK = 16  # pixels per work-item row chunk in the CPU variant (float16 vectors)
GROUP = 4   # PSFs blended per pass over the taps in the CPU variant (int4 of ids)
ROWS_ADJ = 3  # output rows accumulated together in the CPU adjoint (an input row serves them all)
ROWS_COL = 30  # output rows per work-item of the CPU adjoint (input rows built once per column)
CPU_GROUP_ITEMS = 8  # work-items (chunk columns) per work-group in the CPU variant


class ClBlur:
    """Forward blur ``F`` and adjoint ``F^T`` on the device, for one kernel field.

    Parameters
    ----------
    runtime : rtdefocus.cl.runtime.ClRuntime
        Context, queue and program cache.
    psfs : (N, k, k) float32, k odd, unit sum
        Measured PSFs, ``psf[k//2 + v, k//2 + u] = k(u, v)`` (not flipped).
    idx : (H, W, 4) int32
        PSF indices per pixel (unused slots: index 0, weight 0).
    wts : (H, W, 4) float32
        Blend weights per pixel.
    channels : int
        C of the planar images ``(C, H, W)`` this instance processes (1 or 3).
    variant : {"cpu", "gpu"}, optional
        Kernel shape; default "gpu" on a GPU device, else "cpu".

    Attributes
    ----------
    shape : tuple
        ``(C, H, W)`` of the images :meth:`forward` and :meth:`adjoint` take.
    psfs : (N, k', k') float32
        The PSFs on the host, as checked and cut to the widest support (zero taps only).
    support : (N,) int32
        Each PSF's exact support half-width (:func:`~rtdefocus.reference.blur.psf_support`).
    variant : str
    """

    #: Skip the zero taps beyond each PSF's support (False: every tap of the k x k window, as
    #: before; ``tools/bench_video.py`` compares both in one run).
    use_support = True
    #: CPU variant: per group and kernel row, skip the taps beyond that row's extent (the zero
    #: corners of disk-shaped PSFs; zero taps only); False: the group's square support.
    use_row_extent = True

    def __init__(self, runtime, psfs: np.ndarray, idx: np.ndarray, wts: np.ndarray,
                 channels: int = 3, variant: str | None = None):
        # pyopencl on first use, not at import: NumPy-only runs skip its start-up cost.
        import pyopencl as cl
        import pyopencl.array as cla

        psfs, idx, wts = check_field(psfs, idx, wts)
        # Only the taps inside the PSFs' support cost time: cut the common size to the widest
        # support (zero taps only: the same operator), and the CPU variant loops over each
        # group's own support (the blurs of a corner range from r ~ 1.5 to 6 px).
        sup = psf_support(psfs, 1.0)
        if not self.use_support:                      # benchmarks: the whole k x k window
            sup = np.full(len(psfs), psfs.shape[1] // 2, np.int32)
        # (radius >= 1: the CPU adjoint's row prologue and epilogue must not overlap)
        r0 = psfs.shape[1] // 2
        r1 = min(r0, max(int(sup.max()), 1))
        psfs = np.ascontiguousarray(psfs[:, r0 - r1:r0 + r1 + 1, r0 - r1:r0 + r1 + 1])
        self.support = sup
        if channels not in (1, 3):
            raise InputError(f"channels must be 1 or 3; got {channels}.")
        if variant is None:
            variant = "gpu" if runtime.is_gpu else "cpu"
        if variant not in ("cpu", "gpu"):
            raise InputError(f"variant must be 'cpu' or 'gpu'; got {variant!r}.")
        self.runtime = runtime
        self.variant = variant
        self.psfs = psfs
        self.k = int(psfs.shape[1])
        self.radius = self.k // 2
        h, w = idx.shape[:2]
        self.shape = (channels, h, w)
        self._cl, self._cla = cl, cla
        dev = runtime.device
        self._max_wg = int(dev.max_work_group_size)
        self._local_mem = int(dev.local_mem_size)
        q = runtime.queue
        self._psfs = cla.to_device(q, psfs)
        self._h, self._w = np.int32(h), np.int32(w)
        if variant == "gpu":
            self._setup_gpu(idx, wts)
        else:
            self._setup_cpu(idx, wts)

    # ------------------------------------------------------------------ GPU variant
    def _gpu_tile(self, channels: int) -> tuple[int, int]:
        """The largest square tile whose work-group and local tile fit the device."""
        r = self.radius
        for t in (16, 8, 4):
            if t * t > self._max_wg:
                continue
            # adjoint: r tile (C floats) + int4 ids + float4 weights per tile pixel
            need = (t + 2 * r) ** 2 * 4 * (channels + 8)
            if need <= self._local_mem:
                return t, t
        raise DeviceError(
            f"kernel radius {r} needs more local memory than the device's {self._local_mem} "
            "bytes even with 4x4 tiles; use variant='cpu' or smaller PSFs.")

    def _setup_gpu(self, idx, wts):
        cla = self._cla
        q = self.runtime.queue
        c, h, w = self.shape
        tx, ty = self._gpu_tile(c)
        defines = {"VARIANT_GPU": 1, "K": self.k, "RADIUS": self.radius, "CHANNELS": c,
                   "TILE_X": tx, "TILE_Y": ty}
        prg = self.runtime.program("blur.cl", defines)
        self._idx = cla.to_device(q, idx)
        self._wts = cla.to_device(q, wts)
        self._local = (tx, ty)
        self._global = (-(-w // tx) * tx, -(-h // ty) * ty)
        # one Kernel object per instance (pyopencl creates a new one on each attribute access)
        self._k_fwd = self._cl.Kernel(prg, "blur_forward_gpu")
        self._k_adj = self._cl.Kernel(prg, "blur_adjoint_gpu")
        log.debug("ClBlur gpu: %dx%d tiles, defines %s", tx, ty, defines)

        def run(kernel, src, dst, wait_for):
            return kernel(q, self._global, self._local, src.data, dst.data, self._psfs.data,
                          self._idx.data, self._wts.data, self._h, self._w, wait_for=wait_for)

        self._run_fwd = lambda s, d, wf: run(self._k_fwd, s, d, wf)
        self._run_adj = lambda s, d, wf: run(self._k_adj, s, d, wf)

    # ------------------------------------------------------------------ CPU variant
    def _setup_cpu(self, idx, wts):
        cla = self._cla
        q = self.runtime.queue
        c, h, w = self.shape
        r = self.radius
        # row segments x0 - halo ... x0 + 15 + halo: a whole number of float16 vectors
        halo = 8 * max(1, -(-r // 8))
        nch = -(-w // CHUNK)
        nby = -(-h // ROWS_COL)
        n_psfs = self._psfs.shape[0]
        goff, gids, gw = chunk_groups(idx, wts, n_psfs)
        agoff, agids, arows = block_groups(pixel_members(idx, wts, n_psfs), r, ROWS_COL)
        lx_f, ly_f = self._cpu_local(nch, h)
        lx_a, ly_a = self._cpu_local(nch, nby)
        defines = {"VARIANT_CPU": 1, "K": self.k, "RADIUS": r, "CHANNELS": c,
                   "HALO": halo, "ROWS_ADJ": ROWS_ADJ, "ROWS_COL": ROWS_COL,
                   "RING": 1 << (ROWS_ADJ + 2 * r - 1).bit_length()}
        prg_f = self.runtime.program("blur.cl", {**defines, "LX": lx_f, "LY": ly_f})
        prg_a = self.runtime.program("blur.cl", {**defines, "LX": lx_a, "LY": ly_a})
        self._bufs = [cla.to_device(q, a) for a in (goff, gids, gw, agoff, agids, arows)]
        # per group, the widest support of its PSFs (empty slots, -1, count as 0)
        sup = np.append(self.support, 0).astype(np.int32)
        asup = sup[agids].max(1).astype(np.int32)
        # per group and kernel row, the taps' extent |u| (-1: an all-zero row, skipped)
        rext = row_extents(self.psfs)
        if not self.use_row_extent:                   # benchmarks: the square support
            v = np.abs(np.arange(self.k) - r)
            rext = np.where(v[None] <= self.support[:, None], self.support[:, None], -1)
        tables = (group_row_extents(rext, gids), asup, group_row_extents(rext, agids))
        self._bufs += [cla.to_device(q, a) for a in tables]
        b_goff, b_gids, b_gw, b_agoff, b_agids, b_arows, b_gext, b_asup, b_aext = (
            b.data for b in self._bufs)
        gl_f = (-(-nch // lx_f) * lx_f, -(-h // ly_f) * ly_f)
        gl_a = (-(-nch // lx_a) * lx_a, -(-nby // ly_a) * ly_a)
        k_f = self._cl.Kernel(prg_f, "blur_forward_cpu")
        k_a = self._cl.Kernel(prg_a, "blur_adjoint_cpu")
        i32 = np.int32
        log.debug("ClBlur cpu: %d chunk groups (%.2f per chunk), %d block groups (%.2f per "
                  "block), local %s / %s", len(gids), len(gids) / max(1, h * nch), len(agids),
                  len(agids) / max(1, nby * nch), (lx_f, ly_f), (lx_a, ly_a))

        def run_fwd(src, dst, wait_for):
            return k_f(q, gl_f, (lx_f, ly_f), src.data, dst.data, self._psfs.data, b_goff,
                       b_gids, b_gw, b_gext, self._h, self._w, i32(nch), wait_for=wait_for)

        def run_adj(src, dst, wait_for):
            return k_a(q, gl_a, (lx_a, ly_a), src.data, dst.data, self._psfs.data, b_goff,
                       b_gids, b_gw, b_agoff, b_agids, b_arows, b_asup, b_aext, self._h,
                       self._w, i32(nch), i32(nby), wait_for=wait_for)

        self._run_fwd, self._run_adj = run_fwd, run_adj

    def _cpu_local(self, nx: int, ny: int) -> tuple[int, int]:
        """An explicit work-group: PoCL's own choice can leave a core idle (whole launch in one
        group); aim for many groups per compute unit, within the device's limit."""
        lx = max(1, min(nx, CPU_GROUP_ITEMS, self._max_wg))
        return lx, 1

    # ------------------------------------------------------------------ public API
    def _check(self, arr, what: str):
        if tuple(arr.shape) != self.shape or arr.dtype != np.float32:
            raise InputError(f"{what} must be a float32 device array of shape {self.shape} "
                             f"(C, H, W); got {arr.dtype} {tuple(arr.shape)}.")
        if not arr.flags.c_contiguous or arr.offset:
            raise InputError(f"{what} must be C-contiguous with zero offset; pass a fresh "
                             "pyopencl.array.Array (e.g. .copy()).")

    def _check_pair(self, src, dst, op: str) -> None:
        self._check(src, "src")
        self._check(dst, "dst")
        if src.data == dst.data:
            raise InputError(f"{op} cannot work in place: src and dst must be different arrays.")

    def forward(self, src, dst, wait_for=None):
        """Enqueue ``dst = F src`` (no host synchronisation).

        Parameters
        ----------
        src, dst : pyopencl.array.Array, (C, H, W) float32, distinct
        wait_for : list of pyopencl.Event, optional

        Returns
        -------
        pyopencl.Event
        """
        self._check_pair(src, dst, "forward")
        return self._run_fwd(src, dst, wait_for)

    def adjoint(self, src, dst, wait_for=None):
        """Enqueue ``dst = F^T src`` (no host synchronisation).

        Parameters
        ----------
        src, dst : pyopencl.array.Array, (C, H, W) float32, distinct
        wait_for : list of pyopencl.Event, optional

        Returns
        -------
        pyopencl.Event
        """
        self._check_pair(src, dst, "adjoint")
        return self._run_adj(src, dst, wait_for)

    def _host(self, img: np.ndarray, op) -> np.ndarray:
        img = np.asarray(img)
        flat = img.ndim == 2
        planes = img[None] if flat else img
        if planes.shape != self.shape:
            raise InputError(f"image must be {self.shape} (C, H, W)"
                             f"{' or (H, W)' if self.shape[0] == 1 else ''}; got {img.shape}.")
        q = self.runtime.queue
        src = self._cla.to_device(q, np.ascontiguousarray(planes, dtype=np.float32))
        dst = self._cla.empty(q, self.shape, np.float32)
        op(src, dst)
        out = dst.get(queue=q)
        return out[0] if flat else out

    def forward_host(self, img: np.ndarray) -> np.ndarray:
        """``F img`` for a host image (C, H, W) (or (H, W) when C = 1); float32, same shape."""
        return self._host(img, self.forward)

    def adjoint_host(self, img: np.ndarray) -> np.ndarray:
        """``F^T img`` for a host image (C, H, W) (or (H, W) when C = 1); float32, same shape."""
        return self._host(img, self.adjoint)


def chunk_groups(idx: np.ndarray, wts: np.ndarray, n_psfs: int):
    """Per 16-pixel row chunk, the distinct PSFs with a nonzero weight, in groups of 4.

    Parameters
    ----------
    idx, wts : (H, W, 4) int32 / float32
        The kernel field's per-pixel indices and weights.
    n_psfs : int

    Returns
    -------
    goff : (H * NCH + 1,) int32
        CSR offsets: chunk ``y * NCH + cx`` owns groups ``goff[i] .. goff[i + 1] - 1``.
    gids : (G, 4) int32
        PSF ids per group, -1 in empty slots.
    gw : (G, 4, 16) float32
        Weight of each id at each pixel of the chunk (duplicate slots summed, 0 past W).
    """
    h, w = idx.shape[:2]
    nch = -(-w // CHUNK)
    pad = nch * CHUNK - w
    ids = np.pad(idx, ((0, 0), (0, pad), (0, 0)))
    ws = np.pad(wts, ((0, 0), (0, pad), (0, 0)))
    # (H, NCH, 64) candidates: element e is pixel e // 4, slot e % 4 of the chunk.
    ids = ids.reshape(h, nch, CHUNK * 4)
    ws = ws.reshape(h, nch, CHUNK * 4)
    px = np.broadcast_to(np.arange(CHUNK * 4, dtype=np.int64) // 4, ids.shape)
    ids = np.where(ws != 0, ids, n_psfs)          # sentinel n_psfs: no contribution
    order = np.argsort(ids, axis=-1)
    ids_s = np.take_along_axis(ids, order, -1)
    ws_s = np.take_along_axis(ws, order, -1)
    px_s = np.take_along_axis(px, order, -1)
    valid = ids_s < n_psfs
    first = np.ones_like(valid)
    first[..., 1:] = ids_s[..., 1:] != ids_s[..., :-1]
    distinct = first & valid
    rank = np.cumsum(distinct, axis=-1) - 1       # rank of each element's id within its chunk
    count = distinct.sum(-1).reshape(-1)
    ngroups = -(-count // GROUP)
    goff = np.zeros(h * nch + 1, np.int64)
    np.cumsum(ngroups, out=goff[1:])
    n_groups = int(goff[-1])
    base = goff[:-1].reshape(h, nch, 1)
    grp = base + rank // GROUP
    slot = rank % GROUP
    gids = np.full((n_groups, GROUP), -1, np.int32)
    gids[grp[distinct], slot[distinct]] = ids_s[distinct]
    flat = (grp[valid] * GROUP + slot[valid]) * CHUNK + px_s[valid]
    gw = np.bincount(flat, weights=ws_s[valid].astype(np.float64),
                     minlength=n_groups * GROUP * CHUNK).astype(np.float32)
    return goff.astype(np.int32), gids, gw.reshape(n_groups, GROUP, CHUNK)


def row_extents(psfs: np.ndarray) -> np.ndarray:
    """(N, k) int32: per PSF and kernel row ``k // 2 + v``, the largest ``|u|`` of a nonzero tap
    in that row (-1 where the row is all zero).

    Parameters
    ----------
    psfs : (N, k, k), ``psf[k//2 + v, k//2 + u] = k(u, v)``
    """
    psfs = np.asarray(psfs)
    r = psfs.shape[2] // 2
    dist = np.abs(np.arange(psfs.shape[2]) - r)
    return np.where(psfs != 0, dist, -1).max(-1).astype(np.int32)


def group_row_extents(rext: np.ndarray, gids: np.ndarray) -> np.ndarray:
    """(G, k) int32: per group of PSF ids (-1 for an empty slot) and kernel row, the widest
    extent of its PSFs' rows (:func:`row_extents`); -1 where every PSF of the group has a zero
    row there. Taps beyond it are zero in every PSF of the group: skipping them changes
    nothing."""
    table = np.vstack([rext, np.full((1, rext.shape[1]), -1, rext.dtype)])   # id -1: empty
    return np.ascontiguousarray(table[gids].max(1), dtype=np.int32)


def pixel_members(idx: np.ndarray, wts: np.ndarray, n_psfs: int) -> np.ndarray:
    """(H, W, ceil(N / 8)) uint8: per pixel, the bitset (little bit order) of its PSFs."""
    h, w = idx.shape[:2]
    bits = np.zeros((h, w, -(-n_psfs // 8)), np.uint8)
    for j in range(idx.shape[2]):
        used = wts[..., j] != 0
        byte, bit = idx[..., j] // 8, (idx[..., j] % 8).astype(np.uint8)
        for b in range(bits.shape[2]):
            bits[..., b] |= np.where(used & (byte == b), np.left_shift(1, bit), 0).astype(np.uint8)
    return bits


def block_groups(bits: np.ndarray, radius: int, rows: int):
    """Per column block (``rows`` rows x 1 chunk), the distinct PSFs the adjoint there needs.

    The adjoint at y uses the kernels of every x = y + u, |u| <= radius, so a block's PSF list
    is the union of the pixel lists over rows ``y0 - radius .. y0 + rows - 1 + radius`` and
    columns ``x0 - radius .. x0 + 15 + radius`` (exactly those pixels: a wider union would
    split more blocks into two passes).

    Parameters
    ----------
    bits : (H, W, B) uint8 bitsets from :func:`pixel_members`
    radius, rows : int

    Returns
    -------
    agoff : (NBY * NCH + 1,) int32, CSR offsets per block ``by * NCH + cx``
    agids : (GA, 4) int32, PSF ids per group (ascending), -1 in empty slots
    arows : (GA, 2) int32, first and last input row where the group's PSFs have a nonzero
        weight within the block's column reach (a second group then skips the rest)
    """
    h, w, nb = bits.shape
    nch = -(-w // CHUNK)
    nby = -(-h // rows)
    # OR over the columns each chunk reaches: x0 - radius ... x0 + 15 + radius
    padded = np.zeros((h, nch * CHUNK + 2 * radius, nb), np.uint8)
    padded[:, radius:radius + w] = bits
    chunks = np.zeros((h, nch, nb), np.uint8)
    for d in range(CHUNK + 2 * radius):
        chunks |= padded[:, d:d + nch * CHUNK:CHUNK]
    # OR over the rows of each block plus the vertical reach
    padded = np.zeros((nby * rows + 2 * radius, nch, nb), np.uint8)
    padded[radius:radius + h] = chunks
    span = np.zeros((nby * rows, nch, nb), np.uint8)
    for d in range(2 * radius + 1):
        span |= padded[d:d + nby * rows]
    region = np.bitwise_or.reduce(span.reshape(nby, rows, nch, nb), axis=1)
    flags = np.unpackbits(region.reshape(nby * nch, nb), axis=-1, bitorder="little")
    blk, ids = np.nonzero(flags)                  # sorted by block, then id
    count = np.bincount(blk, minlength=nby * nch)
    ngroups = -(-count // GROUP)
    agoff = np.zeros(nby * nch + 1, np.int64)
    np.cumsum(ngroups, out=agoff[1:])
    start = np.zeros(nby * nch + 1, np.int64)
    np.cumsum(count, out=start[1:])
    rank = np.arange(len(blk)) - start[blk]
    n_groups = int(agoff[-1])
    gsel = agoff[blk] + rank // GROUP
    agids = np.full((n_groups, GROUP), -1, np.int32)
    agids[gsel, rank % GROUP] = ids
    # rows of each group's reach where any of its PSFs has weight
    gflags = np.zeros((n_groups, nb * 8), bool)
    gflags[gsel, ids] = True
    gbits = np.packbits(gflags, axis=-1, bitorder="little")          # (GA, nb)
    gblock = np.repeat(np.arange(nby * nch), ngroups)
    g_by, g_cx = gblock // nch, gblock % nch
    reach = np.arange(rows + 2 * radius)
    arows = np.zeros((n_groups, 2), np.int32)
    for start in range(0, n_groups, 4096):       # bounded memory for large fields
        sl = slice(start, start + 4096)
        sub = padded[g_by[sl, None] * rows + reach, g_cx[sl, None]]  # (g, reach, nb)
        hit = (sub & gbits[sl, None, :]).any(-1)
        first = hit.argmax(1)
        last = hit.shape[1] - 1 - hit[:, ::-1].argmax(1)
        arows[sl, 0] = g_by[sl] * rows - radius + first
        arows[sl, 1] = g_by[sl] * rows - radius + last
    return agoff.astype(np.int32), agids, arows
