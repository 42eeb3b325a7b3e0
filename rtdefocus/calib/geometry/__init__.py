"""The geometry stage: line patterns -> planes, their homographies and folds -> the lit area.

Modules, one step each (DESIGN.md §4):

* :mod:`.stage` — :func:`calibrate_geometry`, :class:`GeometryOptions`: the stage itself;
* :mod:`.structured_light` — line patterns, Gray-code labels, sub-pixel ridges;
* :mod:`.fold` — kinks in the lines -> the folds;
* :mod:`.homography` — line crossings -> one homography per plane;
* :mod:`.planes` — how many planes, which crossing is on which, where they meet;
* :mod:`.fit` — detected lines -> planes, homographies, folds (:func:`~.fit.fit_geometry`);
* :mod:`.lens` — the camera lens's radial distortion, fitted with the geometry (or given);
* :mod:`.dense` — dense structured light (option ``dense``): every camera pixel's projector
  coordinates, Gray code plus phase shift;
* :mod:`.dense_fit` — the planes' homographies and residual fields from the dense map, and the
  region no plane fits;
* :mod:`.diagnostics` — the picture of the stage's result over the camera view.

The plane geometry itself (homographies per plane, folds, bounding boxes, labels) is
:mod:`rtdefocus.planar`, shared with the warps and the kernels.
"""

from .stage import OPTIONS, GeometryDetail, GeometryOptions, calibrate_geometry

__all__ = ["GeometryOptions", "OPTIONS", "GeometryDetail", "calibrate_geometry"]
