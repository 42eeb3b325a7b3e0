"""OpenCL runtime: choose a device, build programs from ``kernels/*.cl`` once per context.

Device choice, in order:

1. ``RTDEFOCUS_DEVICE``: ``"P:D"`` (platform and device index, as ``rtdefocus info`` lists them)
   or a case-insensitive substring of the device or platform name (``"pocl"``, ``"nvidia"``);
2. ``PYOPENCL_CTX`` (PyOpenCL's own convention, e.g. ``"0:1"``);
3. otherwise the first GPU, else the first device of any type.

Programs are memoised per (context, file, options); PyOpenCL's disk cache (keyed on source,
included headers, options and driver) makes rebuilds in later processes cheap.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import warnings
from dataclasses import dataclass, field

from ..errors import DeviceError, ProgramBuildError
from ..resources import kernel_source, kernels_dir

log = logging.getLogger(__name__)

def install_hint(platform: str | None = None) -> str:
    """Which OpenCL driver to install on ``platform`` (``sys.platform``: linux, darwin, win32)."""
    platform = platform or sys.platform
    if platform.startswith("win"):
        return ("Install an OpenCL driver: your GPU's graphics driver from NVIDIA, AMD or Intel "
                "carries one; with no GPU, Intel's 'CPU Runtime for OpenCL Applications'.")
    if platform == "darwin":
        return ("Install an OpenCL driver: `pip install pocl-binary-distribution` (a CPU driver "
                "PyOpenCL finds by itself).")
    return ("Install an OpenCL driver: `pip install pocl-binary-distribution` (CPU, no root), or "
            "`sudo apt-get install pocl-opencl-icd` (Debian/Ubuntu), or your GPU vendor's OpenCL "
            "driver (NVIDIA, AMD ROCm, Intel compute-runtime).")


INSTALL_HINT = install_hint()


def import_pyopencl():
    try:
        import pyopencl as cl
    except ImportError as exc:  # pragma: no cover - pyopencl is a hard dependency
        raise DeviceError(f"pyopencl is not importable ({exc}); run `pip install pyopencl`.") from exc
    return cl


def list_devices() -> list[tuple[int, int, object, object]]:
    """All OpenCL devices as ``(platform_index, device_index, platform, device)``.

    Raises :class:`DeviceError` (naming the fix) when no platform is installed.
    """
    cl = import_pyopencl()
    try:
        platforms = cl.get_platforms()
    except cl.Error as exc:  # PLATFORM_NOT_FOUND_KHR when no ICD is installed
        raise DeviceError(f"No OpenCL platform found ({exc}). {INSTALL_HINT}") from exc
    out = []
    for pi, plat in enumerate(platforms):
        try:
            devices = plat.get_devices()
        except cl.Error:
            continue
        out.extend((pi, di, plat, dev) for di, dev in enumerate(devices))
    if not out:
        raise DeviceError(f"OpenCL platforms exist but expose no device. {INSTALL_HINT}")
    return out


def _pick(spec: str | None, source: str):
    cl = import_pyopencl()
    devices = list_devices()
    names = ", ".join(f"{pi}:{di} {d.name.strip()} ({p.name.strip()})" for pi, di, p, d in devices)
    if spec:
        spec = spec.strip()
        parts = spec.split(":")
        if all(s.strip().isdigit() for s in parts) and 1 <= len(parts) <= 2:
            pi = int(parts[0])
            di = int(parts[1]) if len(parts) == 2 else 0
            for p_i, d_i, _, dev in devices:
                if (p_i, d_i) == (pi, di):
                    return dev
        else:
            for _, _, plat, dev in devices:
                if spec.lower() in dev.name.lower() or spec.lower() in plat.name.lower():
                    return dev
        raise DeviceError(
            f"{source}={spec!r} matches no OpenCL device. Use 'P:D' indices or a name substring; "
            f"available: {names}. Unset {source} to pick automatically."
        )
    gpus = [d for _, _, _, d in devices if d.type & cl.device_type.GPU]
    return gpus[0] if gpus else devices[0][3]


def choose_device():
    """The OpenCL device selected by the environment (see module docstring)."""
    if os.environ.get("RTDEFOCUS_DEVICE"):
        return _pick(os.environ["RTDEFOCUS_DEVICE"], "RTDEFOCUS_DEVICE")
    if os.environ.get("PYOPENCL_CTX"):
        return _pick(os.environ["PYOPENCL_CTX"], "PYOPENCL_CTX")
    return _pick(None, "")


@dataclass
class ClRuntime:
    """A context and in-order queue on one device, with a per-context program cache."""

    device: object
    #: Extra context properties (GL sharing: :mod:`rtdefocus.cl.glshare`); None for a plain one.
    properties: list | None = None
    context: object = field(init=False)
    queue: object = field(init=False)
    _programs: dict = field(init=False, default_factory=dict)
    _lock: threading.Lock = field(init=False, default_factory=threading.Lock)

    def __post_init__(self):
        cl = import_pyopencl()
        self.context = (cl.Context([self.device], properties=self.properties) if self.properties
                        else cl.Context([self.device]))
        self.queue = cl.CommandQueue(self.context)

    @property
    def is_gpu(self) -> bool:
        return bool(self.device.type & import_pyopencl().device_type.GPU)

    @property
    def description(self) -> str:
        return f"{self.device.name.strip()} ({self.device.platform.name.strip()})"

    def program(self, filename: str, defines: dict | None = None):
        """Build (once) and return the program in ``kernels/<filename>`` with ``-D`` defines."""
        options = [f"-D{k}={v}" for k, v in sorted((defines or {}).items())]
        options += ["-I", str(kernels_dir()), *BUILD_OPTIONS]
        key = (filename, tuple(options))
        with self._lock:
            prg = self._programs.get(key)
            if prg is None:
                prg = build_program(self.context, filename, options)
                self._programs[key] = prg
        return prg


#: Options every program is built with (beside its -D defines and the include path).
#: Denormals flushed to zero: a converging solve fills its fields (momentum differences,
#: residuals near black) with subnormal floats, which x86 handles in microcode; on PoCL that
#: doubled a FISTA iteration within 24 iterations of a still frame (800x600 cubicle: 8 -> 16
#: ms). They carry nothing an 8-bit picture can show; GPUs flush them under this option too.
BUILD_OPTIONS = ("-cl-denorms-are-zero",)


def build_program(context, filename: str, options: list[str]):
    """Build ``kernels/<filename>``; raise :class:`ProgramBuildError` with the full log on failure."""
    cl = import_pyopencl()
    src = kernel_source(filename)
    try:
        # PoCL prints harmless notes (e.g. about unrolling); PyOpenCL turns any compiler output
        # into a warning. Keep it in the debug log instead of on the user's terminal.
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", cl.CompilerWarning)
            prg = cl.Program(context, src).build(options=options)
        for w in caught:
            if issubclass(w.category, cl.CompilerWarning):
                log.debug("OpenCL compiler output for %s %s: %s", filename, options, w.message)
            else:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        return prg
    except cl.RuntimeError as exc:
        dev = ", ".join(d.name.strip() for d in context.devices)
        raise ProgramBuildError(filename, options, dev, str(exc)) from exc


_runtime: ClRuntime | None = None
_runtime_lock = threading.Lock()


def get_runtime() -> ClRuntime:
    """The process-wide runtime on the chosen device (created on first use)."""
    global _runtime
    with _runtime_lock:
        if _runtime is None:
            _runtime = ClRuntime(choose_device())
            log.info("OpenCL device: %s", _runtime.description)
        return _runtime


def opencl_available() -> tuple[bool, str]:
    """``(True, description)`` when a device can be used, else ``(False, reason)``."""
    try:
        return True, get_runtime().description
    except DeviceError as exc:
        return False, str(exc)


#: What each caller does with NumPy when it fell back (``choose_backend``'s ``doing``): one
#: warning per process for each.
_fallback_warned: set[str] = set()


def choose_backend(backend: str, doing: str, logger: logging.Logger) -> str:
    """"opencl" or "numpy" for a requested ``backend`` ("auto", "opencl", "numpy").

    "auto" falls back to NumPy when no OpenCL device is usable, with one warning per process
    for each ``doing`` (e.g. "compensating"), logged on the caller's ``logger`` with the
    driver to install; "opencl" then raises :class:`DeviceError`.
    """
    if backend == "numpy":
        return "numpy"
    ok, why = opencl_available()
    if ok:
        return "opencl"
    if backend == "opencl":
        raise DeviceError(f"backend='opencl' requested but no OpenCL device is usable: {why}")
    if doing not in _fallback_warned:
        hint = "" if INSTALL_HINT in why else " " + INSTALL_HINT
        logger.warning("no OpenCL device; %s with the (slow) NumPy backend: %s%s", doing, why, hint)
        _fallback_warned.add(doing)
    return "numpy"
