"""Real cameras and projectors: what :class:`rtdefocus.HardwareProCam` and the live camera
source share.

``camera``   open a camera (FOURCC before size, then rate), log what it negotiated, read with
             retry, re-open after a dropped stream, drain by time.
``camera_controls`` lock exposure, white balance, focus, sharpening per capture backend (V4L2,
             DirectShow, Media Foundation), read them back and report what did not take.
``sync``     projector-to-camera latency (black→white, timed), a coarse projector→camera map,
             and the check that a captured frame shows the pattern that was shown.
``preflight`` the seconds-long check before the minutes of calibration (``rtdefocus check``).
"""

from .camera import Camera, CameraSettings, open_camera
from .camera_controls import ControlReport

__all__ = ["Camera", "CameraSettings", "ControlReport", "open_camera"]
