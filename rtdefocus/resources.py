"""Find the OpenCL and GLSL sources shipped in ``rtdefocus.kernels`` (top-level ``kernels/``)."""

from __future__ import annotations

import importlib.resources
from pathlib import Path


def kernels_dir() -> Path:
    """Directory holding the ``*.cl`` / ``*.glsl`` sources (works for wheel and editable installs)."""
    return Path(str(importlib.resources.files("rtdefocus.kernels")))


def kernel_source(name: str) -> str:
    """Text of the kernel or shader file ``name`` (e.g. ``"blur.cl"``, ``"warp.glsl"``)."""
    path = kernels_dir() / name
    if not path.is_file():
        available = sorted(p.name for p in kernels_dir().iterdir() if p.suffix in (".cl", ".glsl"))
        raise FileNotFoundError(f"kernel source {name!r} not found in {kernels_dir()}; "
                                f"available: {available}")
    return path.read_text()
