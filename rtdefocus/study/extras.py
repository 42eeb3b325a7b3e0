"""The study wing's optional dependencies (``pip install 'rtdefocus[demo]'``), loaded on use:
they are slow to import and a plain install does not have them."""

from __future__ import annotations

import importlib
from types import ModuleType

from ..errors import RtDefocusError

#: Import name -> distribution name, for the message.
_DIST = {"skimage": "scikit-image"}


def need(module: str, what: str, hint: str = "") -> ModuleType:
    """``module`` imported, or an error saying that ``what`` needs it and which extra brings it."""
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        dist = _DIST.get(module.split(".")[0], module.split(".")[0])
        raise RtDefocusError(f"{what} needs {dist}: pip install 'rtdefocus[demo]' (or "
                             f"{dist}){hint}") from exc
