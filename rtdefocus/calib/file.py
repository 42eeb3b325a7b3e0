"""The calibration file: one ``.npz`` with a JSON ``meta`` and plain, checked arrays.

Sections (DESIGN.md §7, docs/internals.md): *geometry* (always), *radiometry* and *psf*
(filled by the later calibration stages). Loading uses ``allow_pickle=False`` and checks every
array's presence, shape and dtype; any defect raises one :class:`CalibrationFileError` that
says what is wrong and what to do. Saving is atomic (temporary file + rename), so a crash
never leaves a half-written file where a good one was.

Integrity: ``meta["sha256"]`` is a SHA-256 digest over every array's name, dtype, shape and
bytes and over the rest of the meta (:func:`content_digest`). Shape checks cannot catch an
edit that keeps the shapes (a polygon that lost a vertex, a flipped byte in a kernel), so
``load`` recomputes the digest and refuses a file whose content changed since it was saved.
Files written before the digest existed load with a logged note.
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import json
import logging
import os
import tempfile
import tokenize
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import __version__
from ..checks import check_coords, check_real, check_size
from ..errors import CalibrationFileError, InputError
from ..planar import MAX_PLANES, PlaneLayout, apply_h, apply_h_per_plane, largest_inscribed_rect
from ..residual import check_residual, dense_displacement, displacement

log = logging.getLogger(__name__)

FORMAT_NAME = "rtdefocus-calibration"
FORMAT_VERSION = 4
#: Versions :meth:`Calibration.load` reads: 1 (before the camera's response and lens
#: distortion were recorded; both are then taken as ideal), 2 (one fold line at most:
#: ``fold_proj`` / ``fold_cam``, read as a layout of one or two planes), 3 (any number of
#: planes: ``folds_proj``, ``folds_cam``, ``fold_planes``; planes exactly flat) and the current
#: one (an optional smooth residual per plane, ``residual_cam``; absent: exactly flat).
READABLE_VERSIONS = (1, 2, 3, 4)
#: meta key of the content digest (hex SHA-256, see :func:`content_digest`).
DIGEST_KEY = "sha256"

# name -> (dtype, shape template); "n" planes, "Hp"/"Wp" projector size, "N" PSFs, "k" kernel,
# "m" polygon vertices, "f" folds. None entries in a template accept any size.
GEOMETRY_ARRAYS = {
    "H_cam_from_proj": (np.float64, ("n", 3, 3)),
    "H_proj_from_cam": (np.float64, ("n", 3, 3)),
    "folds_proj": (np.float64, ("f", 3)),
    "folds_cam": (np.float64, ("f", 3)),
    "fold_planes": (np.int32, ("f", 2)),
    "lit_polygon_cam": (np.float64, ("m", 2)),
}
#: Versions 1 and 2 stored one fold line at most (zeros for one plane).
LEGACY_FOLD_ARRAYS = {
    "fold_proj": (np.float64, (3,)),
    "fold_cam": (np.float64, (3,)),
}
RADIOMETRY_ARRAYS = {
    "response_lut": (np.float32, (3, 256)),
    "ambient_proj": (np.float32, ("Hp", "Wp", 3)),
    "albedo_proj": (np.float32, ("Hp", "Wp", 3)),
}
PSF_ARRAYS = {
    "psf_points_proj": (np.float32, ("N", 2)),
    "psf_plane": (np.int32, ("N",)),
    "psfs": (np.float32, ("N", "k", "k")),
    "pix_idx": (np.int32, ("Hp", "Wp", 4)),
    "pix_wts": (np.float32, ("Hp", "Wp", 4)),
}
#: Version 2: the camera lens (radial distortion, geometry stage) and the camera's inverse
#: response (radiometry stage); absent means an ideal lens and a linear camera.
LENS_ARRAYS = {"camera_distortion": (np.float64, (2,))}
CAMERA_ARRAYS = {"camera_lut": (np.float32, (3, 256))}
#: Version 4: each plane's smooth residual off its homography (:mod:`rtdefocus.residual`),
#: B-spline control points of (dx, dy) camera px; absent means planes that are exactly flat.
RESIDUAL_ARRAYS = {"residual_cam": (np.float64, ("n", "gy", "gx", 2))}
SECTIONS = {"geometry": GEOMETRY_ARRAYS, "radiometry": RADIOMETRY_ARRAYS, "psf": PSF_ARRAYS,
            "lens": LENS_ARRAYS, "camera": CAMERA_ARRAYS, "residual": RESIDUAL_ARRAYS}


def _identity_lut() -> np.ndarray:
    return np.tile(np.linspace(0.0, 1.0, 256, dtype=np.float32), (3, 1))


@dataclass
class Calibration:
    """Everything learnt about one projector-camera-surface arrangement.

    Geometry: ``H_cam_from_proj`` / ``H_proj_from_cam`` (n, 3, 3) float64 per plane (n = 1 ..
    :data:`~rtdefocus.planar.MAX_PLANES`); the folds between them, ``folds_proj`` /
    ``folds_cam`` (f, 3) float64 lines ``a x + b y + c = 0`` (a² + b² = 1) with
    ``fold_planes`` (f, 2) int32 the plane on each fold's negative and positive side (f = 0 for
    one plane; :attr:`layout` reads them as a :class:`~rtdefocus.planar.PlaneLayout`);
    ``lit_polygon_cam`` (m, 2) outline lit by the projector. Two planes: one fold, plane 0 on
    its negative side (``fold_proj`` / ``fold_cam`` give that line).
    Radiometry (optional): ``response_lut`` (3, 256) code -> linear light, ``ambient_proj``,
    ``albedo_proj`` (Hp, Wp, 3). PSF (optional): ``psf_points_proj`` (N, 2), ``psf_plane`` (N,),
    ``psfs`` (N, k, k) unit-sum gather kernels, ``pix_idx`` / ``pix_wts`` (Hp, Wp, 4).
    Camera (optional, format 2): ``camera_distortion`` (2,) float64 radial (k1, k2) of the
    lens (:func:`~rtdefocus.planar.distort_points`; the homographies, fold and outline
    are in undistorted camera pixels), ``camera_lut`` (3, 256) float32 the camera's inverse
    response, code -> linear light.
    Residual (optional, format 4): ``residual_cam`` (n, gy, gx, 2) float64, per plane the
    B-spline control points of a smooth displacement (camera px) added to its homography's
    camera point (:mod:`rtdefocus.residual`): walls that are planes only nearly.
    ``meta`` holds options, statistics and provenance (JSON-serialisable).
    """

    projector_size: tuple[int, int]
    camera_size: tuple[int, int]
    H_cam_from_proj: np.ndarray
    H_proj_from_cam: np.ndarray
    folds_proj: np.ndarray
    folds_cam: np.ndarray
    fold_planes: np.ndarray
    lit_polygon_cam: np.ndarray
    response_lut: np.ndarray | None = None
    ambient_proj: np.ndarray | None = None
    albedo_proj: np.ndarray | None = None
    psf_points_proj: np.ndarray | None = None
    psf_plane: np.ndarray | None = None
    psfs: np.ndarray | None = None
    pix_idx: np.ndarray | None = None
    pix_wts: np.ndarray | None = None
    camera_distortion: np.ndarray | None = None
    camera_lut: np.ndarray | None = None
    residual_cam: np.ndarray | None = None
    meta: dict = field(default_factory=dict)
    #: What the geometry stage saw (:class:`~rtdefocus.calib.geometry.stage.GeometryDetail`), for its
    #: diagnostics picture; in memory only, never saved.
    geometry_detail: object | None = field(default=None, repr=False, compare=False)
    # display_rect answers per (aspect, margin, outline); not a constructor argument.
    _rect_cache: dict = field(default_factory=dict, init=False, repr=False, compare=False)
    # residual_dense's answer, keyed by the identity of residual_cam; not an argument.
    _residual_cache: tuple = field(default=(None, None), init=False, repr=False, compare=False)

    @classmethod
    def with_fold(cls, *, fold_proj=None, fold_cam=None, **kwargs) -> Calibration:
        """A calibration of one or two planes given by one fold line (``fold_proj`` /
        ``fold_cam`` (3,), plane 0 where negative; ignored, may be None or zeros, for one
        plane), as format 2 stored it. Other arguments as the constructor."""
        n = int(np.asarray(kwargs["H_cam_from_proj"]).shape[0])
        if n == 1:
            folds_proj = folds_cam = np.zeros((0, 3))
            planes = np.zeros((0, 2), np.int32)
        else:
            folds_proj = np.asarray(fold_proj, np.float64).reshape(1, 3)
            folds_cam = np.asarray(fold_cam, np.float64).reshape(1, 3)
            planes = np.array([[0, 1]], np.int32)
        return cls(folds_proj=folds_proj, folds_cam=folds_cam, fold_planes=planes, **kwargs)

    # ------------------------------------------------------------------ queries
    @property
    def n_planes(self) -> int:
        return int(self.H_cam_from_proj.shape[0])

    @property
    def layout(self) -> PlaneLayout:
        """The planes in projector pixels (:class:`~rtdefocus.planar.PlaneLayout`)."""
        return PlaneLayout(self.n_planes, self.folds_proj, self.fold_planes)

    @property
    def layout_cam(self) -> PlaneLayout:
        """The planes in (undistorted) camera pixels, same plane numbers."""
        return PlaneLayout(self.n_planes, self.folds_cam, self.fold_planes)

    @property
    def fold_proj(self) -> np.ndarray:
        """The fold line (3,) of a two-plane calibration; zeros for one plane. Several folds:
        InputError naming :attr:`layout` (which handles any number)."""
        return self._single_fold(self.folds_proj, "folds_proj")

    @property
    def fold_cam(self) -> np.ndarray:
        """:attr:`fold_proj` in camera pixels."""
        return self._single_fold(self.folds_cam, "folds_cam")

    def _single_fold(self, folds, name: str) -> np.ndarray:
        folds = np.asarray(folds, np.float64).reshape(-1, 3)
        if len(folds) == 0:
            return np.zeros(3)
        if len(folds) > 1:
            raise InputError(f"this calibration has {self.n_planes} planes and {len(folds)} folds; "
                             f"use calib.layout (or calib.{name}) instead of a single fold line")
        return folds[0].copy()

    @property
    def has_radiometry(self) -> bool:
        return self.response_lut is not None

    @property
    def has_psf(self) -> bool:
        return self.psfs is not None

    @property
    def lut(self) -> np.ndarray:
        """Projector response (3, 256) code -> linear light; identity when not measured."""
        return self.response_lut if self.response_lut is not None else _identity_lut()

    def plane_of(self, x, y) -> np.ndarray:
        """Plane index (int8) of projector pixel(s) (x, y) (:meth:`PlaneLayout.label`; with two
        planes, 0 where ``fold_proj`` is negative).

        ``x``, ``y``: finite numbers or arrays that broadcast together (InputError otherwise).
        """
        x, y = check_coords(x, y, "plane_of position")
        if self.n_planes == 1:
            return np.zeros(np.broadcast(x, y).shape, dtype=np.int8)
        return self.layout.label(x, y)

    def plane_map(self) -> np.ndarray:
        """(Hp, Wp) int8 plane index of every projector pixel."""
        wp, hp = self.projector_size
        ys, xs = np.mgrid[0:hp, 0:wp]
        return self.plane_of(xs, ys)

    def display_rect(self, size: tuple[int, int], margin: float = 0.0) -> tuple[int, int, int, int]:
        """Camera pixels ``(x, y, w, h)`` where an input of ``size = (w, h)`` appears: the largest
        upright rectangle of that aspect inside the lit area, shrunk by ``margin`` (a fraction
        in [0, 0.5)). ``size`` is the input's (width, height) in whole pixels, both >= 1."""
        w, h = check_size(size, "display size")
        margin = check_real(margin, "display margin", lo=0.0)
        if margin >= 0.5:
            raise InputError(f"display margin is a fraction of the rectangle in [0, 0.5); got "
                             f"{margin}")
        # The search scans every camera pixel (~0.1 s): a video asks this for every frame, so
        # remember the answer per aspect, margin and outline (the key changes if the outline does).
        key = (w / h, float(margin), self.lit_polygon_cam.tobytes(), tuple(self.camera_size))
        cache = self._rect_cache
        if key not in cache:
            cache[key] = largest_inscribed_rect(self.lit_polygon_cam, w / h, self.camera_size,
                                                margin)
        return cache[key]

    def residual_dense(self) -> np.ndarray | None:
        """(Hp, Wp, 2) float32 camera px: each projector pixel's plane residual (what the warp
        adds to the homography's camera point), or None when the planes are exactly flat.
        Made once per ``residual_cam`` array and returned as the same (read-only) array."""
        if self.residual_cam is None:
            return None
        key, dense = self._residual_cache
        if key is not self.residual_cam:
            ctrl = check_residual(self.residual_cam, self.n_planes)
            wp, hp = self.projector_size
            yy, xx = np.mgrid[0:hp, 0:wp]
            dense = dense_displacement(ctrl, self.plane_of(xx, yy), self.projector_size)
            dense.setflags(write=False)
            self._residual_cache = (self.residual_cam, dense)
        return dense

    def cam_from_proj(self, x, y) -> np.ndarray:
        """(N, 2) camera points (undistorted camera px) of projector points (x, y): each
        point's plane homography plus that plane's residual when there is one."""
        x = np.asarray(x, np.float64).ravel()
        y = np.asarray(y, np.float64).ravel()
        plane = self.plane_of(x, y).astype(np.intp)
        cx, cy = apply_h_per_plane(self.H_cam_from_proj, plane, x, y)
        out = np.stack([cx, cy], axis=1)
        if self.residual_cam is not None:
            for p in np.unique(plane):
                sel = plane == p
                out[sel] += displacement(self.residual_cam[p], x[sel], y[sel], self.projector_size)
        return out

    def proj_from_cam(self, xc, yc, plane=None, iterations: int = 3) -> tuple[np.ndarray, np.ndarray]:
        """Projector (x, y) of ideal camera points (xc, yc) (arrays of one shape) on the given
        planes (default: the camera layout's label of each point): the inverse homography,
        then, with a residual, fixed-point steps ``x <- H⁻¹(c - d(x))`` (its slope is far below
        one pixel per pixel: each step gains orders of magnitude)."""
        xc = np.asarray(xc, np.float64)
        yc = np.asarray(yc, np.float64)
        if plane is None:
            plane = self.layout_cam.label(xc, yc)
        plane = np.asarray(plane).astype(np.intp)
        mx, my = apply_h_per_plane(self.H_proj_from_cam, plane, xc, yc)
        if self.residual_cam is None:
            return mx, my
        for p in np.unique(plane):
            sel = plane == p
            c = np.stack([xc[sel], yc[sel]], axis=1)
            x = np.stack([mx[sel], my[sel]], axis=1)
            for _ in range(iterations):
                d = displacement(self.residual_cam[p], x[:, 0], x[:, 1], self.projector_size)
                x = apply_h(self.H_proj_from_cam[p], c - d)
            mx[sel], my[sel] = x[:, 0], x[:, 1]
        return mx, my

    def kernel_at(self, x: float, y: float) -> np.ndarray:
        """(k, k) float32 unit-sum gather kernel at projector pixel (x, y) (nearest pixel);
        entry ``[k//2 + v, k//2 + u]`` is k_x((u, v))."""
        xa, ya = check_coords(x, y, "kernel_at position")
        if xa.ndim or ya.ndim:
            raise InputError(f"kernel_at takes one position (two numbers); got arrays of shape "
                             f"{xa.shape} and {ya.shape} — call it once per position")
        if self.psfs is None:
            raise CalibrationFileError("this calibration has no PSF section (geometry only); "
                                       "run `rtdefocus calibrate` with the kernel stage enabled")
        wp, hp = self.projector_size
        xi = int(np.clip(round(float(xa)), 0, wp - 1))
        yi = int(np.clip(round(float(ya)), 0, hp - 1))
        idx, wts = self.pix_idx[yi, xi], self.pix_wts[yi, xi]
        k = np.tensordot(wts.astype(np.float64), self.psfs[idx].astype(np.float64), axes=1)
        s = k.sum()
        return (k / s if s > 0 else k).astype(np.float32)

    # ------------------------------------------------------------------ I/O
    def _arrays(self) -> dict[str, np.ndarray]:
        out = {}
        for names in SECTIONS.values():
            for name, (dtype, _) in names.items():
                value = getattr(self, name)
                if value is not None:
                    out[name] = np.ascontiguousarray(value, dtype=dtype)
        return out

    def sections(self) -> list[str]:
        arrays = self._arrays()
        return [s for s, names in SECTIONS.items() if all(n in arrays for n in names)]

    def validate(self) -> None:
        """Check every array's shape and dtype against the format; raise CalibrationFileError."""
        _check_arrays(self._arrays(), self.projector_size, "<in memory>")

    def save(self, path: str | os.PathLike) -> Path:
        """Write atomically to ``path``; returns the path written.

        A name that does not end in ``.npz`` gets it appended (``setup`` -> ``setup.npz``, as
        NumPy does); :meth:`load` applies the same rule, so either spelling finds the file.
        The file records a SHA-256 content digest that :meth:`load` verifies.
        """
        self.validate()
        given = Path(path)
        path = npz_path(given)
        if path != given:
            log.info("calibration saved as %s (a calibration file ends in .npz)", path)
        meta = {
            "format": FORMAT_NAME,
            "format_version": FORMAT_VERSION,
            "rtdefocus_version": __version__,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "projector_size": list(self.projector_size),
            "camera_size": list(self.camera_size),
            "sections": self.sections(),
            **{k: v for k, v in self.meta.items() if k not in ("format", "format_version")},
        }
        # The digest covers the meta as it will read back (NumPy scalars became numbers).
        meta = json.loads(json.dumps(meta, default=json_default))
        meta.pop(DIGEST_KEY, None)
        arrays = self._arrays()
        meta[DIGEST_KEY] = content_digest(meta, arrays)
        payload = {"meta": np.array(json.dumps(meta))}
        payload.update(arrays)
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
        try:
            with os.fdopen(fd, "wb") as fh:
                # mkstemp creates the file 0600; a calibration is an ordinary shareable file.
                if hasattr(os, "fchmod"):
                    os.fchmod(fh.fileno(), 0o644)
                np.savez_compressed(fh, **payload)
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        return path

    @classmethod
    def load(cls, path: str | os.PathLike, *, verify: bool = True) -> Calibration:
        """Read and check a calibration file.

        Parameters
        ----------
        path : str or PathLike
            The file; ``setup`` finds ``setup.npz`` as :meth:`save` wrote it (the name as
            given is read when only it exists).
        verify : bool
            Check the content digest (default). ``False`` is for experts who edited a file on
            purpose: the digest is not enforced (a warning is logged when it does not match);
            the shapes, dtypes and values are still checked.

        Raises
        ------
        CalibrationFileError
            Missing, truncated, foreign, of another format version, malformed, or damaged or
            edited since it was saved (digest mismatch); one error naming the file and the fix.
        """
        given = Path(path)
        path = npz_path(given)
        if not path.is_file() and given.is_file():
            path = given
        if not path.is_file():
            tried = repr(str(given)) if path == given else f"{str(given)!r} nor {str(path)!r}"
            raise CalibrationFileError(f"calibration file {tried} does not exist; create one "
                                       "with `rtdefocus calibrate ... -o FILE.npz`")
        # np.load treats anything that is not a zip or .npy as a pickle, so random bytes would
        # be reported as "pickled objects": check the zip signature first.
        with open(path, "rb") as fh:
            magic = fh.read(4)
        if magic not in (b"PK\x03\x04", b"PK\x05\x06"):
            raise CalibrationFileError(f"{str(path)!r} is not an .npz archive (it starts with "
                                       f"{magic!r}); recalibrate or restore a good copy")
        try:
            with np.load(path, allow_pickle=False) as npz:
                data = {k: npz[k] for k in npz.files}
        except ValueError as exc:
            if "pickle" in str(exc).lower():
                raise CalibrationFileError(
                    f"{str(path)!r} holds pickled Python objects, which rtdefocus never writes and "
                    "will not load (unsafe); recalibrate to get a clean file") from exc
            raise CalibrationFileError(f"{str(path)!r} is not a readable .npz ({exc}); "
                                       "recalibrate or restore a good copy") from exc
        except (zipfile.BadZipFile, zlib.error, OSError, EOFError, NotImplementedError,
                RuntimeError, KeyError, SyntaxError, tokenize.TokenError) as exc:
            # A flipped bit fails the zip CRC, the inflater or the header (compression method);
            # one that reaches an array's .npy header before the CRC is checked can leave it
            # unparseable (numpy's literal_eval raises TokenError / SyntaxError there).
            raise CalibrationFileError(f"{str(path)!r} is damaged, truncated or not an .npz "
                                       f"archive ({exc}); recalibrate or restore a good copy") \
                from exc
        if "meta" not in data:
            raise CalibrationFileError(f"{str(path)!r} is an .npz but not an rtdefocus calibration "
                                       "(no 'meta' entry)")
        try:
            meta = json.loads(str(data.pop("meta")))
        except (json.JSONDecodeError, TypeError) as exc:
            raise CalibrationFileError(f"{str(path)!r}: its 'meta' is not valid JSON ({exc})") from exc
        fmt = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        if fmt != FORMAT_NAME:
            raise CalibrationFileError(f"{str(path)!r} is not an rtdefocus calibration "
                                       f"(format {fmt!r})")
        version = meta.get("format_version")
        if version not in READABLE_VERSIONS:
            raise CalibrationFileError(
                f"{str(path)!r} has calibration format version {version}, this rtdefocus reads "
                f"versions {READABLE_VERSIONS}; recalibrate with this version")
        try:
            psize = tuple(int(v) for v in meta["projector_size"])
            csize = tuple(int(v) for v in meta["camera_size"])
        except (KeyError, TypeError, ValueError) as exc:
            raise CalibrationFileError(f"{str(path)!r}: meta lacks projector/camera size") from exc
        _verify(data, meta, psize, str(path), verify, legacy=version < 3)
        if version < 3:
            data = _folds_from_legacy(data)
        kwargs = {name: data.get(name) for names in SECTIONS.values() for name in names}
        for name in ("H_cam_from_proj", "H_proj_from_cam", "folds_proj", "folds_cam",
                     "lit_polygon_cam"):
            kwargs[name] = kwargs[name].astype(np.float64)
        drop = {"format", "format_version", "rtdefocus_version", "created", "projector_size",
                "camera_size", "sections", DIGEST_KEY}
        calib = cls(projector_size=psize, camera_size=csize,
                    meta={k: v for k, v in meta.items() if k not in drop}, **kwargs)
        calib.meta["loaded_from"] = {"path": str(path), "created": meta.get("created"),
                                     "rtdefocus_version": meta.get("rtdefocus_version")}
        return calib


def npz_path(path: str | os.PathLike) -> Path:
    """The file :meth:`Calibration.save` writes for ``path``: ``.npz`` appended unless the
    name already ends in it (``setup`` -> ``setup.npz``, ``setup.v2`` -> ``setup.v2.npz``)."""
    path = Path(path)
    return path if path.suffix == ".npz" else path.with_name(path.name + ".npz")


def content_digest(meta: dict, arrays: dict[str, np.ndarray]) -> str:
    """Hex SHA-256 over the meta (without its digest, keys sorted) and every array's name,
    dtype, shape and bytes, in name order: any change of a value, a shape or a type changes it."""
    h = hashlib.sha256()
    body = {k: v for k, v in meta.items() if k != DIGEST_KEY}
    h.update(json.dumps(body, sort_keys=True, separators=(",", ":")).encode())
    for name in sorted(arrays):
        arr = np.ascontiguousarray(arrays[name])
        h.update(f"\n{name}|{arr.dtype.str}|{arr.shape}|".encode())
        h.update(arr.tobytes())
    return h.hexdigest()


def _folds_from_legacy(data: dict) -> dict:
    """Format 1-2 arrays with the one fold line (zeros for one plane) as format 3's folds."""
    data = dict(data)
    fold_proj, fold_cam = data.pop("fold_proj"), data.pop("fold_cam")
    if data["H_cam_from_proj"].shape[0] == 1:
        data["folds_proj"] = data["folds_cam"] = np.zeros((0, 3))
        data["fold_planes"] = np.zeros((0, 2), np.int32)
    else:
        data["folds_proj"], data["folds_cam"] = fold_proj.reshape(1, 3), fold_cam.reshape(1, 3)
        data["fold_planes"] = np.array([[0, 1]], np.int32)
    return data


def _verify(data: dict, meta: dict, projector_size, where: str, verify: bool,
            legacy: bool = False) -> None:
    """Check the arrays, then the content digest; a digest mismatch is reported as damage or
    an edit (with the first structural defect found, if any), since it is the likelier story
    than a file written wrong by rtdefocus itself."""
    problem = None
    try:
        _check_arrays(data, projector_size, where, legacy)
    except CalibrationFileError as exc:
        problem = exc
    stored = meta.get(DIGEST_KEY)
    if stored is None:
        log.info("%s has no content digest (written before rtdefocus recorded one): its integrity "
                 "cannot be checked; save it again to add one", where)
    elif content_digest(meta, data) != stored:
        if verify:
            detail = f"; first defect found: {str(problem).replace(where + ': ', '')}" \
                if problem else ""
            raise CalibrationFileError(
                f"{where} is damaged or was edited since it was saved: its content does not match "
                f"the SHA-256 digest recorded in it{detail}. Restore a good copy or recalibrate "
                "(an expert who edited it on purpose can load it with "
                "Calibration.load(path, verify=False))") from problem
        log.warning("%s: content digest does not match (damaged or edited since it was saved); "
                    "loading anyway because verify=False", where)
    elif not verify:
        log.warning("%s: loading with verify=False; the content digest matches", where)
    if problem is not None:
        raise problem


def json_default(obj):
    """``json.dumps(default=...)`` for NumPy scalars and arrays and paths."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON-serialisable: {type(obj).__name__}")


def _check_arrays(arrays: dict, projector_size, where: str, legacy: bool = False) -> None:
    sections = SECTIONS
    if legacy:      # formats 1-2: one fold line instead of the fold lists
        geometry = {k: v for k, v in GEOMETRY_ARRAYS.items()
                    if k not in ("folds_proj", "folds_cam", "fold_planes")}
        sections = {**SECTIONS, "geometry": {**geometry, **LEGACY_FOLD_ARRAYS}}
    known = {n for names in sections.values() for n in names}
    unknown = sorted(set(arrays) - known)
    if unknown:
        raise CalibrationFileError(f"{where}: unknown entries {unknown}; the file is foreign or "
                                   "from another version — recalibrate")
    wp, hp = projector_size
    dims: dict[str, int] = {"Hp": hp, "Wp": wp}
    for section, names in sections.items():
        present = [n for n in names if n in arrays]
        if section == "geometry" and len(present) < len(names) or 0 < len(present) < len(names):
            missing = sorted(set(names) - set(present))
            raise CalibrationFileError(f"{where}: the {section} section is incomplete, missing "
                                       f"{missing}; recalibrate")
        for name in present:
            dtype, template = names[name]
            arr = arrays[name]
            if arr.dtype != dtype:
                raise CalibrationFileError(f"{where}: {name} has dtype {arr.dtype}, expected "
                                           f"{np.dtype(dtype).name}")
            if arr.ndim != len(template):
                raise CalibrationFileError(f"{where}: {name} has shape {arr.shape}, expected "
                                           f"{len(template)} dimensions {template}")
            for axis, (want, got) in enumerate(zip(template, arr.shape, strict=True)):
                if isinstance(want, str):
                    want = dims.setdefault(want, got)
                if want != got:
                    raise CalibrationFileError(
                        f"{where}: {name} has shape {arr.shape}, expected {template} with "
                        f"{dict(dims)} (axis {axis}: {got} != {want})")
            if arr.dtype.kind == "f" and not np.isfinite(arr).all():
                raise CalibrationFileError(f"{where}: {name} contains NaN or infinite values")
    n = dims.get("n")
    if n is None or not 1 <= n <= MAX_PLANES:
        raise CalibrationFileError(f"{where}: {n} planes; rtdefocus handles 1 to {MAX_PLANES}")
    if legacy and n > 2:
        raise CalibrationFileError(f"{where}: {n} planes in a format-1/2 file, which holds one "
                                   "fold at most; recalibrate")
    if not legacy:
        try:
            PlaneLayout(n, arrays["folds_proj"], arrays["fold_planes"])
            PlaneLayout(n, arrays["folds_cam"], arrays["fold_planes"])
        except InputError as exc:
            raise CalibrationFileError(f"{where}: the folds do not describe {n} planes ({exc}); "
                                       "recalibrate") from None
    if "k" in dims and dims["k"] % 2 == 0:
        raise CalibrationFileError(f"{where}: PSF size {dims['k']} must be odd")
    if "pix_idx" in arrays:
        idx = arrays["pix_idx"]
        if idx.min() < 0 or idx.max() >= dims["N"]:
            raise CalibrationFileError(f"{where}: pix_idx refers to PSFs outside 0..{dims['N'] - 1}")
