"""The radiometry stage: the projector's response, the ambient term and the albedo, in the
camera's linear light.

Modules:

* :mod:`.stage` — :func:`calibrate_radiometry`, :class:`RadiometryOptions`: the stage itself;
* :mod:`.camera_response` — the camera's response (codes -> linear light), known or recovered;
* :mod:`.exposure` — over/under-exposure and exposure drift checks between white frames.
"""

from .stage import OPTIONS, RadiometryOptions, calibrate_radiometry, linearize_camera

__all__ = ["RadiometryOptions", "OPTIONS", "calibrate_radiometry", "linearize_camera"]
