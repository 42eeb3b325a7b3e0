"""Timing of the virtual set-up's camera (benchmarks)."""

from __future__ import annotations

import time

import numpy as np

from .patterns import test_pattern
from .virtual_procam import VirtualProCam


def capture_seconds(procam: VirtualProCam | None = None, repeats: int = 5,
                    sharp: bool = False) -> float:
    """Median wall time (s) of one ``capture`` of the checker pattern (after one warm-up)."""
    procam = procam or VirtualProCam("cubicle")
    pat = test_pattern("checker", procam.projector_size)
    procam.capture(pat, sharp=sharp)
    times = []
    for _ in range(max(1, repeats)):
        t0 = time.perf_counter()
        procam.capture(pat, sharp=sharp)
        times.append(time.perf_counter() - t0)
    return float(np.median(times))
