"""Cost of the set-up views on the host: `aim`'s analysis and preview picture of a 1280x720
camera frame (the virtual cubicle showing the checker, 800x600 projector), and `play
--preview`'s picture of a 1280x800 projector frame. Medians of repeated calls, milliseconds.

    python tools/bench_setup_views.py
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from rtdefocus import sim
from rtdefocus.hardware import aim
from rtdefocus.stream.preview import compose_preview

PROJ, CAM = (800, 600), (1280, 720)


def median_ms(fn, n: int = 15) -> float:
    times = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def main() -> None:
    pc = sim.VirtualProCam("cubicle", projector_size=PROJ, camera_size=(1280, 960), seed=0)

    def capture(pattern):
        return cv2.resize(pc.capture(pattern), CAM, interpolation=cv2.INTER_AREA)

    white = capture(aim.aim_pattern("white", PROJ))
    black = capture(np.zeros((PROJ[1], PROJ[0], 3), np.uint8))
    checker = capture(aim.aim_pattern("checker", PROJ))
    area = aim.find_projected_area(white, black)
    view = aim.analyse(checker, area, pattern="checker", projector_size=PROJ)
    rows = {
        "aim: find_projected_area (1280x720)": median_ms(lambda: aim.find_projected_area(white, black)),
        "aim: analyse, checker (1280x720)": median_ms(
            lambda: aim.analyse(checker, area, pattern="checker", projector_size=PROJ)),
        "aim: compose_aim_frame -> 960x540": median_ms(
            lambda: aim.compose_aim_frame(checker, area=view.area, clipped=view.clipped,
                                          regions=view.regions, readings=view.readings,
                                          pattern="checker", size=(960, 540))),
    }
    frame = (np.random.default_rng(0).random((800, 1280, 3)) * 255).astype(np.uint8)
    rows["play --preview: compose_preview 1280x800 -> 480x330"] = median_ms(
        lambda: compose_preview(frame, ["0" * 40] * 3, (480, 330)), 50)
    for name, ms in rows.items():
        print(f"{name:55s} {ms:7.1f} ms")
    meters = ", ".join(f"{r.name} {x.blur_projector_px:.2f} px"
                       for r, x in zip(view.regions, view.readings, strict=True))
    print(f"focus meter on the cubicle: {meters}")


if __name__ == "__main__":
    main()
