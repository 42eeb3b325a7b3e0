"""What a timing was taken on: CPU, cores, load, library versions and the OpenCL device."""

from __future__ import annotations

import os
import platform
import re
from pathlib import Path

import numpy as np


def machine_info(runtime=None) -> dict:
    """CPU (model name), cores, load average, Python / NumPy / OpenCV versions, and the OpenCL
    device: ``runtime``'s in detail when given, else the default device's description (or why
    there is none)."""
    cpu = platform.processor() or "unknown"
    try:
        m = re.search(r"^model name\s*:\s*(.+)$", Path("/proc/cpuinfo").read_text(), re.M)
        cpu = m.group(1).strip() if m else cpu
    except OSError:
        pass
    info = {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(),
            "numpy": np.__version__, "platform": platform.platform()}
    try:
        info["loadavg"] = os.getloadavg()
    except OSError:
        pass
    try:
        import cv2
        info["opencv"] = cv2.__version__
    except ImportError:
        pass
    if runtime is None:
        try:
            from ..cl.runtime import get_runtime
            info["device"] = get_runtime().description
        except Exception as exc:  # noqa: BLE001 - a description only
            info["device"] = f"none ({exc})"
        return info
    dev = runtime.device
    info.update(device=runtime.description, device_type="GPU" if runtime.is_gpu else "CPU",
                driver=dev.driver_version, opencl=dev.platform.version,
                compute_units=dev.max_compute_units, max_work_group_size=dev.max_work_group_size,
                local_mem_bytes=dev.local_mem_size)
    return info
