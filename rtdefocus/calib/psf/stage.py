"""Defocus kernels (the PSF stage): measured dot PSFs at a few sample points -> the kernel field F.

Gather form (DESIGN.md §3, docs/internals.md): pixel x's kernel is ``k_x = Σ_j w_j ψ_{s_j}``, a
blend of at most 4 measured PSFs of x's *own* plane. A dot at projector pixel y measures column
y of F, m(x) = k_x(x − y) ≈ k_y(x − y), so ``psf[k//2 + v, k//2 + u] = m(y + (u, v))``: a
shift, not a flip.

The stage, step by step (every step only calls ``capture``):

1. **Pilot** (1 capture): 3×3 squares on a coarse grid; their spread gives a blur radius per
   grid point, fitted per plane (the grid is made finer, down to half its spacing, until every
   plane has six dots: a narrow side wall would otherwise get one column and no gradient). For
   a thin lens r = A·f·|1/D_focus − 1/D| with 1/D affine on
   a plane, so r is affine on each wall (or |affine| where the wall crosses the focus), and its
   lines of equal blur are straight. The fit sets each dot's size and measuring window, the
   dot spacing, how far from the fold the fold samples go, and where samples are needed.
2. **Layout** (``layout``): ``"paper"`` — each plane's 4 corners (inset) plus 2 points on the
   fold, blended bilinearly as in the paper (§2.4); ``"default"`` — the plane's corners,
   points along every fold on *each* side just farther from it than the local blur (each dot
   lights one wall only, yet measures the kernel at the fold; the two sides are staggered so
   they share a pattern; where three planes meet, their corners are moved apart into their
   planes so that they share one too), and lines of equal predicted blur ``radius_step`` px of radius apart,
   each sampled every ``max_spacing`` px: blending two discs of different radii is a poor disc
   (Δr = 1 px gives ~15-20 % error mid-way), so the blur's own gradient sets the density;
   ``"dense"`` — a regular grid per plane. Samples that would share a dot's window with a
   corner or fold sample are dropped, so a layout fits in as few patterns as it can (one, on
   the presets). ``cross_fold=True`` is the geometry-blind baseline the paper argues against:
   the frame laid out as one plane (one affine radius fit) and blended across the fold; the
   measurement itself is the same for every layout.
3. **Dots** (a handful of captures): as many per pattern as fit with their light apart; each
   pattern is averaged over ``averages`` captures (the rest of the ``psf_captures`` budget).
   Where the predicted blur is small the dot is one projector pixel (bright enough, measured
   with no deconvolution, so the rim stays sharp); where it is wide a 1-px dot's light spreads
   over ~πr² pixels and drowns in camera noise, so the dot is 2×2 or 3×3 px and the box is
   deconvolved by the next step (with a small ridge) — on the simulator this halves the error
   of the faint, wide kernels and costs a little rim sharpness. The three camera channels are
   summed (one field serves all channels).
4. **Back to projector pixels, exactly**: the camera samples the projector-space light at each
   camera pixel's projector position (through the homography of the wall that camera pixel
   sees, so a dot on the fold is handled too), i.e. bilinearly between projector pixel
   centres. So each dot's kernel is the least-squares solution of ``camera = bilinear(kernel ⊛
   dot) + local affine background`` over the camera pixels of its window, the kernel unknown
   only inside a disc bounded by the pilot's radius (which suppresses the noise tails and
   needs no black frame: the background is fitted around each dot from the same averaged
   captures). With ~2.5 camera pixels per projector pixel this is well determined, sub-pixel,
   and energy-consistent (camera values are radiance). Then one white capture, against the
   white frame the dots were normalised by: a camera whose exposure drifted over the stage
   stops the calibration with the fix (:func:`~..exposure.check_end_white`).
5. **Averaging and clean-up**: each raw LS kernel (divided by its energy: the albedo is α's
   business) is averaged with its plane's kernels of the same predicted blur nearby
   (:func:`iso_average`): along a line of equal blur a thin lens's kernel is the same, so this
   cuts the noise where it dominates (wide, faint kernels, e.g. at a concave fold); on a plane
   whose pilot is only a constant guess (fewer than 4 dots) nothing is averaged. Raw, so
   the zero-mean noise averages away. Then the averaged kernel's equivalent disc radius
   r = sqrt(2 E[u² + v²]) sets a tighter support (1.15 r + 1.2 px); outside it, and below 2
   noise sigmas (the noise ring around a wide kernel), the kernel is 0; the sum is normalised
   to 1. The common window k (odd) is set by the largest support.
6. **F**: per pixel, indices and weights of ≤ 4 PSFs of its plane — barycentric on a per-plane
   Delaunay triangulation (``default``, ``dense``; outside the samples' hull: the nearest hull
   edge, clamped) or bilinear on quads (``paper``). Never across a fold unless ``cross_fold``:
   a pixel blends only its own plane's samples (and, ``paper``, the ends of its plane's folds).

Modules, one per step: :mod:`.pilot` (1), :mod:`.sampling` (2), :mod:`.dots` (3-5), :mod:`.kernel_field`
(6), :mod:`.diagnostics` (pictures). This module holds the stage: its options and
:func:`calibrate_psf`, built from :class:`PsfRun` (pilot -> plans -> one measurement -> a field
per plan), which :mod:`rtdefocus.study.eval_layouts` also uses to compare layouts on one measurement.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, fields

import numpy as np

from ...checks import check_choice
from ..capture import Capturer, check_capturer, check_geometry
from ..file import Calibration
from ..options import stage_options
from ..radiometry.stage import linearize_camera
from .diagnostics import psf_diagnostics, radius_map
from .dots import (
    MIN_SNR,
    Measurement,
    clean_kernel,
    common_window,
    dot_geometry,
    dot_sizes,
    equivalent_radius,
    iso_average,
    measure_psfs,
    pack_patterns,
)
from .kernel_field import interpolation_field
from .pilot import FOLD, RadiusModel, fold_code, pilot_radius
from .sampling import LAYOUTS, SamplePlan, fold_segment, fold_segments, plan_samples

log = logging.getLogger(__name__)

# Kernel values below this many noise sigmas (of the averaged kernel) are set to 0: inside the
# support a wide kernel's plateau is several sigmas up, while the noise in the ring between its
# rim and the support bound would otherwise add mass (and inflate the radius by ~0.3 px).
# 2 sigmas: on the simulator 0, 1, 2 give interior errors 0.083, 0.081, 0.077 (cubicle).
_NOISE_FLOOR = 2.0
# Region labels of kernels averaged with no other (above every plane and fold code).
_OWN_REGION = 1 << 20


def iso_regions(planes: np.ndarray, model: RadiusModel) -> np.ndarray:
    """The regions :func:`~.dots.iso_average` averages within: each sample's plane (or fold
    code), except on a plane whose pilot gave no gradient (too few dots: a "constant" guess),
    where no line of equal blur is known: there each kernel is a region of its own."""
    planes = np.asarray(planes)
    guessed = np.isin(planes, [r for r, k in model.kind.items() if k == "constant"])
    return np.where(guessed, _OWN_REGION + np.arange(len(planes)), planes)


@dataclass(frozen=True)
class PsfOptions:
    """Options of the PSF stage, with their defaults (``calibrate(**options)`` routes these
    names to :func:`calibrate_psf`).

    Attributes
    ----------
    layout : ``"default"`` | ``"paper"`` | ``"dense"`` (module docstring, step 2).
    fold_samples : samples along the fold on each side (None: one per max_spacing / 2).
    averages : captures averaged per dot pattern (None: the ``psf_captures`` budget left
        after the pilot, shared among the patterns).
    cross_fold : the geometry-blind baseline: one region, blended across the fold.
    radius_step, max_spacing : default layout: predicted blur-radius step between lines of
        equal blur (px), and largest sample spacing along and across them (px).
    dense_spacing : dense layout grid step (px).
    edge_inset : sample distance from the frame edges (px).
    psf_captures : capture budget of the stage when ``averages`` is not given (one more
        white frame at the stage's end checks that the exposure held still).
    dot_size : ``"auto"`` or the side of the square dot (px). 1 px measures the kernel
        directly; a larger dot gives dot_size² more light and is deconvolved by the LS model
        (with a small ridge). ``"auto"`` uses 1 px where the predicted blur is small (bright
        enough) and 2-3 px where it is large (a 1-px dot is then too faint against the noise).
    pilot_spacing : grid step of the pilot dots (px), made finer down to half of it where a
        plane gets fewer than six dots; that half must exceed ~3x the largest blur radius.
    iso_tolerance, iso_distance : each PSF is averaged with the PSFs of its plane whose
        predicted radius is within ``iso_tolerance`` px, up to ``iso_distance`` px away
        (:func:`~.dots.iso_average`); ``iso_tolerance=0`` keeps every PSF as measured.
    """

    layout: str = "default"
    fold_samples: int | None = None
    averages: int | None = None
    cross_fold: bool = False
    radius_step: float = 0.5
    max_spacing: float = 150.0
    dense_spacing: float = 50.0
    edge_inset: float = 2.0
    psf_captures: int = 20
    dot_size: int | str = "auto"
    pilot_spacing: int = 100
    iso_tolerance: float = 0.15
    iso_distance: float = 160.0


#: names of the stage's options (the fields of :class:`PsfOptions`).
OPTIONS = tuple(f.name for f in fields(PsfOptions))


def psf_options(options: PsfOptions | None = None, **overrides) -> PsfOptions:
    """``options`` (default: the defaults) with keyword ``overrides``; InputError naming the
    valid options for an unknown one (:func:`~rtdefocus.calib.options.stage_options`)."""
    return stage_options(PsfOptions, options, **overrides)


@dataclass
class Dots:
    """One measurement of the union of several plans' points (step 3-5 for all of them)."""

    index: dict          # (x, y) -> row of ``meas``
    meas: Measurement
    averages: int
    captures: int        # the stage's captures so far (pilot + dots + the end white frame)
    white_drift: list | None = None   # the white frame's change over the stage (R, G, B)


@dataclass
class PsfRun:
    """The PSF stage of one calibration run, step by step: :meth:`start` (validation and the
    pilot), :meth:`plan` per ``(layout, cross_fold)``, :meth:`measure` (the union of the plans'
    points, measured once), :meth:`fill` per plan. :func:`calibrate_psf` does this for one plan.
    """

    calib: Calibration
    capture: Capturer
    options: PsfOptions
    camera_lut: float | np.ndarray    # the camera's inverse response (linearize_camera)
    first_count: int                    # the capturer's psf count before this run
    model: RadiusModel
    blind: RadiusModel | None = None    # one affine fit over the frame (cross-fold baseline)
    normalise: object | None = None     # frame_normaliser: codes -> I / (W − B) − background

    @classmethod
    def start(cls, calib: Calibration, capture: Capturer, options: PsfOptions,
              layouts) -> PsfRun:
        """Check the options, begin the stage's captures and take the pilot (step 1)."""
        for lay, _ in layouts:
            check_choice(lay, LAYOUTS, "layout")
        dot_sizes(np.zeros(1), options.dot_size)       # validates
        # The camera's inverse response from the radiometry stage (linear when not measured).
        camera_lut = calib.camera_lut if calib.camera_lut is not None else 1.0
        # + 1: the white frame taken after the dots for the exposure-drift check.
        capture.begin("psf", options.psf_captures + 1)
        n0 = capture.counts.get("psf", 0)
        norm = frame_normaliser(calib, capture, camera_lut)
        # 1. pilot (per plane, and a blind single-region fit for the cross-fold baseline)
        model = pilot_radius(calib, capture, spacing=options.pilot_spacing,
                             camera_lut=camera_lut, normalise=norm)
        blind = None
        if any(cf for _, cf in layouts):
            # What a method unaware of the fold assumes: one plane, so one affine radius.
            blind = RadiusModel(model.points, model.radii)
            blind.fit(0, force_affine=True)
        return cls(calib, capture, options, camera_lut, n0, model, blind, norm)

    def plan(self, key: tuple[str, bool]) -> SamplePlan:
        """The sample plan of ``(layout, cross_fold)`` (step 2)."""
        o = self.options
        return plan_samples(self.calib, self.blind if key[1] else self.model, key[0],
                            cross_fold=key[1], dot_size=o.dot_size, fold_samples=o.fold_samples,
                            radius_step=o.radius_step, max_spacing=o.max_spacing,
                            dense_spacing=o.dense_spacing, edge_inset=o.edge_inset)

    def measure(self, plans: list[SamplePlan]) -> Dots:
        """Measure the union of the plans' points once (steps 3-5); the averages default to
        what the first plan would get on its own."""
        calib, capture, o, model = self.calib, self.capture, self.options, self.model
        uniq: dict[tuple[int, int], int] = {}
        upts, uplane = [], []
        for plan in plans:
            for (x, y), p in zip(plan.points.tolist(), plan.planes, strict=True):
                if (x, y) not in uniq:
                    uniq[(x, y)] = len(upts)
                    upts.append((x, y))
                    uplane.append(int(p))
        upts_a = np.array(upts, int)
        # Every dot is measured the same way whatever layout asked for it: its window and dot
        # size follow the per-plane pilot model (a dot on the fold: the larger of the two sides).
        uplane_a = np.array(uplane)
        if calib.n_planes > 1:
            on_plane = uplane_a >= 0               # not on a fold (fold_code < 0)
            uplane_a[on_plane] = calib.plane_of(upts_a[on_plane, 0], upts_a[on_plane, 1])
        urad_a = np.empty(len(upts_a))
        for p in np.unique(uplane_a):
            sel = uplane_a == p
            urad_a[sel] = model(upts_a[sel].astype(np.float64),
                                int(p) if calib.n_planes > 1 else 0)
        used = capture.counts.get("psf", 0) - self.first_count
        averages = o.averages
        if averages is None:
            # What the first layout would get on its own: its patterns share the budget left.
            first = np.array([uniq[(int(x), int(y))] for x, y in plans[0].points])
            n_first = len(pack_patterns(upts_a[first], *dot_geometry(
                urad_a[first], dot_sizes(urad_a[first], o.dot_size))))
            averages = max(2, (o.psf_captures - used) // n_first)
        meas = measure_psfs(calib, capture, upts_a, urad_a, averages=averages,
                            camera_lut=self.camera_lut, dot_size=o.dot_size,
                            normalise=self.normalise)
        log.info("psf: %d dots in %d patterns x %d averages; radius %.2f..%.2f px; snr %.0f..%.0f",
                 len(upts_a), meas.patterns, averages, meas.radius.min(), meas.radius.max(),
                 meas.snr.min(), meas.snr.max())
        drift = self.end_drift()
        total = capture.counts.get("psf", 0) - self.first_count
        return Dots(uniq, meas, averages, int(total), np.round(drift, 4).tolist())

    def end_drift(self) -> np.ndarray:
        """One white capture after the dots against the white frame every dot was normalised
        by (the radiometry stage's, or this stage's own): an auto-exposure that drifted over
        the stage raises :class:`CalibrationError` naming the fix (:mod:`..exposure`)."""
        from ..radiometry.exposure import check_end_white

        wp, hp = self.calib.projector_size
        white, black = (self.capture.mean_frame(key, np.full((hp, wp, 3), value, np.uint8),
                                                self.capture.frame_count(key))
                        for key, value in (("white", 255), ("black", 0)))
        return check_end_white(self.capture, self.calib, white, black, self.camera_lut)

    def fill(self, target: Calibration, key: tuple[str, bool], plan: SamplePlan,
             dots: Dots) -> Calibration:
        """Fill ``target``'s psf section from the plan's PSFs: averaged, cleaned, a common
        window, the field (steps 5-6)."""
        o, meas = self.options, dots.meas
        sel = np.array([dots.index[(int(x), int(y))] for x, y in plan.points])
        # Average the raw LS kernels (zero-mean noise averages away; clipped noise would not),
        # then clean: a support from each averaged kernel's radius, and a floor at the noise
        # left after averaging, which removes the faint noise ring around wide kernels.
        raw = common_window([meas.raw[i] for i in sel], meas.bound[sel])
        skipped = fill_skipped(raw, plan, meas.skipped[sel] if meas.skipped is not None else
                               np.zeros(len(sel), bool))
        n_eff = np.ones(len(raw))
        noise = meas.noise[sel].copy()
        if skipped.any():
            # A filled-in kernel is an average of measured ones: its own noise is about theirs,
            # and it must not weigh in the averages below as if it were a measurement.
            noise[skipped] = float(np.median(noise[~skipped]))
        if o.iso_tolerance > 0:
            signed = plan.radius if plan.radius_signed is None else plan.radius_signed
            regions = iso_regions(plan.planes, self.blind if key[1] else self.model)
            raw, n_eff = iso_average(raw, plan.points, regions, signed,
                                     np.where(skipped, 1e3 * noise, noise), o.iso_tolerance,
                                     o.iso_distance)
        cleaned, tight = [], np.zeros(len(raw))
        for j in range(len(raw)):
            floor = _NOISE_FLOOR * noise[j] / math.sqrt(n_eff[j])
            psf_j, _, tight[j] = clean_kernel(raw[j].astype(np.float64), float(meas.bound[sel[j]]),
                                        floor)
            cleaned.append(psf_j)
        psfs = common_window(cleaned, tight)
        idx, wts = interpolation_field(target, plan)
        target.psf_points_proj = plan.points.astype(np.float32)
        target.psf_plane = plan.planes.astype(np.int32)
        target.psfs = psfs
        target.pix_idx = idx
        target.pix_wts = wts
        target.meta["psf"] = {
            "layout": key[0], "cross_fold": key[1], "samples": int(len(plan)),
            "kinds": {k: int((plan.kinds == k).sum()) for k in np.unique(plan.kinds)},
            "window": int(psfs.shape[1]), "patterns": meas.patterns, "averages": dots.averages,
            "captures": dots.captures, "white_drift": dots.white_drift,
            "dot_sizes": {str(d): int((meas.dots[sel] == d).sum()) for d in np.unique(meas.dots)},
            "radius_range": [round(min(equivalent_radius(p) for p in psfs), 3),
                             round(max(equivalent_radius(p) for p in psfs), 3)],
            "pilot_model": {str(k): v for k, v in
                            (self.blind if key[1] else self.model).kind.items()},
            "median_snr": round(float(np.median(meas.snr[sel])), 1),
            "skipped": [[int(x), int(y)] for x, y in plan.points[skipped]],
            "skipped_why": [_skip_reason(float(v)) for v in meas.snr[sel][skipped]],
            "iso_average": {"tolerance": o.iso_tolerance, "distance": o.iso_distance,
                            "median_n_eff": round(float(np.median(n_eff)), 2)},
        }
        return target


# Camera px: smoothing of the background (ambient / projector light) under the dots.
_BG_SMOOTH = 2.0
# Fewest measured dots a plane (or the fold) needs: its kernel field is blended from them.
_MIN_MEASURED = 3


def _skip_reason(snr: float) -> str:
    """Why a dot was skipped, from its measured signal-to-noise ratio (the diagnostics)."""
    if not snr > 0:
        return "no light above the background"
    if snr < MIN_SNR:
        return f"too faint (SNR {snr:.1f} < {MIN_SNR:g})"
    return "no kernel shape left after cleaning"


def fill_skipped(raw: np.ndarray, plan: SamplePlan, skipped: np.ndarray) -> np.ndarray:
    """Replace the kernels of dots too faint to measure by their neighbours' (in place).

    Each skipped dot takes the average of the measured kernels of its own region weighted by
    closeness in predicted blur radius (0.3 px scale) and in position (150 px scale): on a
    plane the kernel depends on the blur radius, which the pilot predicts. Returns
    ``skipped``.

    Raises
    ------
    CalibrationError
        A region keeps fewer than 3 measured dots: the message names the region and says how
        to get more light to the camera.
    """
    from ...errors import CalibrationError

    skipped = np.asarray(skipped, bool)
    if not skipped.any():
        return skipped
    radius = plan.radius if plan.radius_signed is None else plan.radius_signed
    for reg in np.unique(plan.planes[skipped]):
        mine = plan.planes == reg
        good = np.flatnonzero(mine & ~skipped)
        if len(good) < _MIN_MEASURED:
            where = ("on the fold" if reg == FOLD else f"on fold {fold_code(reg)}") if reg < 0 \
                else f"on plane {int(reg)}"
            raise CalibrationError(
                f"only {len(good)} of {int(mine.sum())} PSF dots {where} could be measured (need "
                f"{_MIN_MEASURED}); the rest are too faint against the camera noise and the room's "
                "light. Darken the room, raise the camera's exposure (without clipping the white "
                "frame) or average more captures (psf_captures)")
        for j in np.flatnonzero(mine & skipped):
            dr = np.abs(radius[good] - radius[j])
            d = np.hypot(*(plan.points[good] - plan.points[j]).T.astype(np.float64))
            w = np.exp(-(dr / 0.3) ** 2 - (d / 150.0) ** 2) + 1e-12
            raw[j] = np.tensordot(w / w.sum(), raw[good], axes=1)
    log.warning("psf: %d of %d dots were too faint to measure and were filled from their "
                "neighbours on the same plane: %s", int(skipped.sum()), len(skipped),
                plan.points[skipped].tolist())
    return skipped


def camera_sides(calib: Calibration) -> list[np.ndarray]:
    """(Hc, Wc) bool masks of the camera pixels of each plane (``calib.layout_cam``, in
    undistorted camera coordinates), one per plane; one all-true mask for a single plane."""
    from ..geometry.lens import ideal_points

    wc, hc = calib.camera_size
    if calib.n_planes == 1:
        return [np.ones((hc, wc), bool)]
    yy, xx = np.mgrid[0:hc, 0:wc].astype(np.float64)
    xy = np.stack([xx, yy], axis=-1)
    xy = ideal_points(calib, xy)
    label = calib.layout_cam.label(xy[..., 0], xy[..., 1])
    return [label == p for p in range(calib.n_planes)]


def frame_normaliser(calib: Calibration, capture: Capturer, camera_lut=1.0):
    """``f(frame) -> (Hc, Wc) float32``: a dot frame's linear light divided by the white
    frame's above the black one (channels summed), less the background (the black frame over
    the same, smoothed within each wall); NaN where the white frame is not clearly brighter
    than the black one.

    This is the dot's light as a fraction of what a full-on projector gives at each camera
    pixel, so the wall's albedo and texture, the shading and the ambient light cancel (they
    would otherwise tilt and shift each dot's profile). The black and white frames are the
    radiometry stage's (reused) or, without it, two captures each.
    """
    import cv2
    from scipy import ndimage

    wp, hp = calib.projector_size
    frames = []
    for key, value in (("black", 0), ("white", 255)):
        n = max(capture.frame_count(key), 2)
        frames.append(linearize_camera(capture.mean_frame(key, np.full((hp, wp, 3), value,
                                                                      np.uint8), n),
                                       camera_lut).sum(axis=2))
    black, white = frames
    span = white - black
    # Divide by the white frame's own light, except where the blur makes it fall off (the
    # frame's edges): there by the nearby full level (a max filter over ~2 blur diameters),
    # so the faint spill beyond the edge is not amplified into noise. The full level is taken
    # within each wall only: across the fold the other wall's (brighter) level would divide
    # the dimmer wall's side of every kernel near the fold and bend it.
    sides = camera_sides(calib)
    env = np.zeros_like(span)
    for side in sides:
        e = cv2.GaussianBlur(ndimage.maximum_filter(np.where(side, span, 0.0), size=31),
                             (0, 0), 5.0)
        env = np.where(side, e, env)
    div = np.maximum(span, 0.9 * env)
    ok = env > 0.05 * float(np.percentile(span, 99))
    inv = np.where(ok, 1.0 / np.where(ok, div, 1.0), 0.0)
    # The background to take off: B / (W − B) is the ambient (and projector black) over the
    # projector's light, smooth within a wall since the albedo and its texture cancel. Taken
    # smoothed within each wall, not B itself: the black frame is averaged over far fewer
    # captures than a dot pattern, and its per-pixel noise would stay in every kernel.
    ratio, bg = black * inv, np.zeros_like(span)
    for side in sides:
        m = (side & ok).astype(np.float64)
        num = cv2.GaussianBlur(ratio * m, (0, 0), _BG_SMOOTH)
        den = cv2.GaussianBlur(m, (0, 0), _BG_SMOOTH)
        bg = np.where(side, num / np.maximum(den, 1e-6), bg)
    inv = np.where(ok, inv, np.nan).astype(np.float32)
    bg = bg.astype(np.float32)

    def normalise(frame: np.ndarray) -> np.ndarray:
        return linearize_camera(frame, camera_lut).sum(axis=2) * inv - bg

    return normalise


def calibrate_psf(calib: Calibration, capture: Capturer, options: PsfOptions | None = None,
                  **overrides) -> Calibration:
    """Measure the defocus kernels and build the kernel field F; fill ``calib``'s psf section.

    Parameters
    ----------
    calib : Calibration
        With the geometry section (radiometry optional: its ``camera_lut`` linearises the
        frames); its psf section is filled in place and it is returned.
    capture : Capturer
        The calibration's capturer (the ProCam, counts, progress, frame cache; stage
        ``"psf"``).
    options : PsfOptions, optional
        The stage's options (default: :class:`PsfOptions`' defaults).
    **overrides
        Fields of :class:`PsfOptions` (``layout="paper"``, ``dot_size=1``, ...) replacing those
        of ``options``.

    Returns
    -------
    Calibration
        ``psf_points_proj`` (N, 2) float32, ``psf_plane`` (N,) int32 (negative: on fold j,
        ``fold_code(j)`` = -1 - j, used by its two planes), ``psfs`` (N, k, k) float32 unit
        sum, ``pix_idx`` (Hp, Wp, 4) int32, ``pix_wts`` (Hp, Wp, 4) float32, and
        ``meta["psf"]`` (layout, counts, radii, window).
    """
    check_capturer(capture)
    o = psf_options(options, **overrides)
    check_geometry(calib, "psf")
    key = (str(o.layout), bool(o.cross_fold))
    run = PsfRun.start(calib, capture, o, [key])
    plan = run.plan(key)
    return run.fill(calib, key, plan, run.measure([plan]))


__all__ = ["calibrate_psf", "PsfOptions", "psf_options", "PsfRun", "Dots", "OPTIONS",
           "LAYOUTS", "FOLD", "pilot_radius", "iso_regions", "plan_samples", "measure_psfs",
           "interpolation_field", "psf_diagnostics", "radius_map", "equivalent_radius",
           "fold_segment", "fold_segments", "fold_code", "pack_patterns", "RadiusModel",
           "SamplePlan", "Measurement"]
