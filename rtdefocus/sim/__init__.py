"""The built-in virtual projector-camera set-up (DESIGN.md §3 and §6).

A pinhole projector at the world origin looks along +z at two vertical half-planes (walls)
that meet at a vertical fold line about 2.5 m away; a pinhole camera beside the projector looks
at the lit area. :class:`VirtualProCam` implements the :class:`rtdefocus.ProCam` protocol, so
calibration learns everything through :meth:`VirtualProCam.capture`; the exact answers are kept
in :attr:`VirtualProCam.truth` (a :class:`GroundTruth`) for tests only.

Modules, one concept each:

* :mod:`~rtdefocus.sim.scene` — :class:`Scene`, :data:`PRESETS`, wall geometry and ray casting;
* :mod:`~rtdefocus.sim.optics` — thin-lens defocus: aperture kernels, :func:`blend_kernel`, the
  kernel field rendered on a grid of radii;
* :mod:`~rtdefocus.sim.virtual_procam` — :class:`VirtualProCam`: irradiance shading, albedo, ambient,
  responses, noise, the camera's view; :func:`capture_seconds`;
* :mod:`~rtdefocus.sim.changes` — :class:`SetupChanges`: ``bump``, ``set_light``, ``refocus``
  between two captures, the truth following;
* :mod:`~rtdefocus.sim.timeline` — :class:`Timeline`: such changes at given times of a clip;
* :mod:`~rtdefocus.sim.truth` — :class:`GroundTruth`;
* :mod:`~rtdefocus.sim.texture` — the "fabric" wall texture;
* :mod:`~rtdefocus.sim.oracle` — :func:`oracle_calibration`, a Calibration from the truth;
* :mod:`~rtdefocus.sim.patterns` — :data:`PATTERNS`, :func:`test_pattern`.
"""

from .changes import SetupChanges
from .optics import RADIUS_STEP, blend_kernel
from .oracle import oracle_calibration
from .patterns import PATTERNS, test_pattern
from .scene import PRESETS, Scene
from .timeline import Event, Timeline
from .timing import capture_seconds
from .truth import GroundTruth
from .virtual_procam import SHADING_MEAN, WEBCAM, VirtualProCam

__all__ = [
    "Event", "GroundTruth", "PATTERNS", "PRESETS", "RADIUS_STEP", "SHADING_MEAN", "Scene", "SetupChanges",
    "Timeline", "VirtualProCam", "WEBCAM",
    "blend_kernel", "capture_seconds", "oracle_calibration", "test_pattern",
]
