"""What a pip install on Linux, macOS or Windows relies on: image files under any name, the
slide cache in the platform's cache folder, no POSIX-only paths or modules in the package, and
one warning naming the OpenCL driver to install when there is none."""

from __future__ import annotations

import logging
import re
import sys
from pathlib import Path

import numpy as np
import pytest

import rtdefocus
from rtdefocus.errors import RtDefocusError
from rtdefocus.imageio import read_image, write_image

PACKAGE = Path(rtdefocus.__file__).parent


@pytest.mark.parametrize("name", ["Café ünï.png", "日本語のスライド.jpg", "Ελληνικά слайд.bmp",
                                  "emoji 🎥.tif"], ids=["latin", "japanese", "greek-cyrillic",
                                                        "emoji"])
def test_images_round_trip_under_non_ascii_names(tmp_path, name):
    yy, xx = np.mgrid[0:23, 0:31]
    img = np.stack([xx * 8, yy * 11, (xx + yy) * 4], axis=2).astype(np.uint8)   # smooth: JPEG-safe
    folder = tmp_path / "présentation"
    path = write_image(folder / name, img, atomic=True)
    assert path.is_file() and sorted(p.name for p in folder.iterdir()) == [name]
    back = read_image(path)
    assert back.shape == img.shape
    if path.suffix == ".jpg":      # lossy: close, not equal
        assert np.abs(back.astype(int) - img).mean() < 4
    else:
        assert np.array_equal(back, img)


def test_image_errors_name_the_file_and_the_fix(tmp_path):
    img = np.zeros((4, 4, 3), np.uint8)
    with pytest.raises(RtDefocusError, match=r"unknown image extension '\.xyz'.*\.png"):
        write_image(tmp_path / "ça.xyz", img)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(RtDefocusError, match="cannot read image .*missing file"):
        read_image(tmp_path / "absent é.png")
    (tmp_path / "not an image.png").write_bytes(b"hello")
    with pytest.raises(RtDefocusError, match="unknown format"):
        read_image(tmp_path / "not an image.png")


def test_cache_folder_is_the_platforms(monkeypatch, tmp_path):
    import platformdirs

    from rtdefocus.stream.cache import default_cache_dir

    monkeypatch.delenv("RTDEFOCUS_CACHE", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    want = Path(platformdirs.user_cache_dir("rtdefocus", appauthor=False))
    assert default_cache_dir() == want
    if sys.platform.startswith("linux"):
        assert want == tmp_path / "xdg" / "rtdefocus"      # Linux honours XDG
    monkeypatch.setenv("RTDEFOCUS_CACHE", str(tmp_path / "mine"))
    assert default_cache_dir() == tmp_path / "mine"


def _code_lines(path: Path):
    """Source lines outside docstrings and comments (a rough cut: enough for literals)."""
    text = path.read_text(encoding="utf-8")
    text = re.sub(r'"""[\s\S]*?"""', "", text)
    for line in text.splitlines():
        yield line.split("#", 1)[0]


def test_no_posix_only_paths_or_modules_in_the_package():
    bad = []
    pattern = re.compile(r"""["'](/tmp|/var/|/home/|~/)|Path\.home\(\)|^\s*import (fcntl|pwd|"""
                         r"""resource|termios)\b|os\.(getuid|fork)\(""")
    for path in sorted(PACKAGE.rglob("*.py")):
        for n, line in enumerate(_code_lines(path), 1):
            if pattern.search(line) and "help=" not in line and '"$RTDEFOCUS' not in line:
                bad.append(f"{path.relative_to(PACKAGE)}:{n}: {line.strip()}")
    assert not bad, "POSIX-only paths or modules:\n" + "\n".join(bad)


@pytest.mark.parametrize(("platform", "names"), [
    ("win32", ("NVIDIA, AMD or Intel", "CPU Runtime for OpenCL")),
    ("darwin", ("pip install pocl-binary-distribution",)),
    ("linux", ("pip install pocl-binary-distribution", "pocl-opencl-icd", "NVIDIA")),
], ids=["windows", "macos", "linux"])
def test_install_hint_names_the_driver_per_os(platform, names):
    from rtdefocus.cl.runtime import install_hint

    hint = install_hint(platform)
    for name in names:
        assert name in hint, (platform, hint)
    if platform == "win32":
        assert "apt-get" not in hint and "pip install pocl" not in hint


def test_no_opencl_runs_on_numpy_with_one_warning_naming_the_driver(monkeypatch, caplog):
    """The reason the runtime gives does not mention a driver (pyopencl failing to load, say):
    the warning still says which one to install."""
    from test_stream import virtual_calibration

    import rtdefocus.cl.runtime as clrt
    from rtdefocus.compensate import compensator as compensator_mod

    calib = virtual_calibration()
    monkeypatch.setattr(clrt, "opencl_available", lambda: (False, "pyopencl: no ICD loader"))
    monkeypatch.setattr(clrt, "_fallback_warned", set())
    with caplog.at_level(logging.WARNING, logger="rtdefocus"):
        a = compensator_mod.Compensator(calib, iterations=1)
        b = compensator_mod.Compensator(calib, iterations=1)
        frame = a.compensate(np.full((24, 32, 3), 128, np.uint8))
    assert a.backend == b.backend == "numpy" and frame.shape == (*calib.projector_size[::-1], 3)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1, warnings
    assert "NumPy" in warnings[0] and clrt.INSTALL_HINT in warnings[0]
