"""OpenCL runtime (device choice, program cache) and the device ops of the compensation."""

from .runtime import ClRuntime, build_program, get_runtime, list_devices, opencl_available

__all__ = ["ClRuntime", "build_program", "get_runtime", "list_devices", "opencl_available"]
