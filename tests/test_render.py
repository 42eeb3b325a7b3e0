"""`rtdefocus render`: a film compensated in chunks on local processes or Dask, its sound copied,
resumable; against the same frames compensated serially in memory."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import rtdefocus as rd
from rtdefocus.errors import InputError
from rtdefocus.film import render
from rtdefocus.film.media import decode_rgb, probe, read_frames, write_film
from rtdefocus.film.plan import plan_chunks

PROJECTOR, CAMERA = (96, 72), (160, 120)
CHUNK, OVERLAP = 8, 4             # 30 frames: 4 chunks, seams at 8, 16 and 24

# Camera-view figures of these renders (deterministic), `tools/measure_gains.py --sections
# render`: the lossless chunked render's largest distance from the serial compensation and its
# smallest gain over geometry only; the default quality's largest codec loss and smallest gain
# over geometry only (dB). Bounds: ACCURACY x the distances, EFFECT x the gains.
ACCURACY, EFFECT = 1.5, 0.85
MEASURED_ARCHIVE = {"off_serial": 0.0200, "gain": 7.601}
MEASURED_DEFAULT = {"codec_loss": 0.1762, "gain": 5.866}


def _procam(noise=None, seed=0):
    return rd.sim.VirtualProCam("cubicle", projector_size=PROJECTOR, camera_size=CAMERA,
                                noise=noise, seed=seed)


def make_film(root: Path) -> dict:
    """A set-up file (the simulator's oracle calibration), a 30-frame film with a tone (still,
    pans, a cut, a zoom, a fade), its decoded frames and their serial compensation."""
    from rtdefocus.sim import oracle_calibration
    from rtdefocus.study.eval_video import QUICK_SEGMENTS, make_clip

    calib = oracle_calibration(_procam())
    setup = root / "setup.npz"
    calib.save(setup)
    path = root / "film.mp4"
    write_film(path, [f for _, f in make_clip(PROJECTOR, QUICK_SEGMENTS)], fps=24)
    info = probe(path)
    inputs = list(read_frames(info, 0, info.n_frames))
    comp = rd.Compensator(calib)
    serial = [comp.compensate(im, iterations=40, warm_start=True) for im in inputs]
    return {"root": root, "setup": setup, "path": path, "calib": calib, "info": info,
            "inputs": inputs, "serial": serial, "comp": comp}


def render_archive(film: dict):
    """The film rendered losslessly on 2 local worker processes, chunk files kept."""
    out = film["root"] / "local.mkv"
    result = render(film["setup"], film["path"], out, quality="archive", workers=2,
                    chunk_frames=CHUNK, overlap=OVERLAP, keep_work=True)
    return result, list(decode_rgb(out))


@pytest.fixture(scope="module")
def film(tmp_path_factory):
    return make_film(tmp_path_factory.mktemp("render"))


@pytest.fixture(scope="module")
def archive(film):
    return render_archive(film)


def archive_figures(film: dict, frames) -> tuple[np.ndarray, np.ndarray]:
    """Per frame, the chunked render's camera-view PSNR off the serial compensation's (dB,
    absolute) and its gain over geometry only (dB)."""
    chunked, serial = _views(film, frames), _views(film, film["serial"])
    geometry = _views(film, [film["comp"].warp(im) for im in film["inputs"]])
    return np.abs(chunked - serial), chunked - geometry


def _views(film, frames, noise=0.0):
    """Camera-view PSNR per frame against the sharp view of the same warp, in the display rect
    (noise > 0: the same noise for every frame list, so that only the frames differ)."""
    from rtdefocus.study.scores import camera_view, psnr, rect_mask

    calib, comp = film["calib"], film["comp"]
    rect = calib.display_rect(film["info"].size)
    mask = rect_mask(rect, (CAMERA[1], CAMERA[0]))
    out = []
    for i, (image, frame) in enumerate(zip(film["inputs"], frames, strict=True)):
        warped = comp.warp(image)
        ref = camera_view(_procam(0.0), calib, warped, sharp=True)
        out.append(psnr(camera_view(_procam(noise, seed=i), calib, frame), ref, mask))
    return np.array(out)


def _audio_packets(path):
    """The audio packets' bytes, and their times (s) from the first video frame."""
    import av

    with av.open(str(path)) as c:
        v0 = min(f.time for f in c.decode(video=0))
    with av.open(str(path)) as c:
        packets = [p for p in c.demux(audio=0) if p.size]
        return [bytes(p) for p in packets], np.array([float(p.pts * p.time_base) - v0
                                                      for p in packets])


def _same_audio(a, b, tol=1.5e-3):
    """Equal packets at equal times (Matroska keeps milliseconds, and shifts every stream
    alike where an audio priming packet starts before 0)."""
    assert len(a[0]) >= 5, "no tone in the film"
    assert a[0] == b[0], "the audio packets differ"
    assert np.abs(a[1] - b[1]).max() <= tol, np.abs(a[1] - b[1]).max()


def test_plan_chunks():
    """Chunks cover the frames once, in order; each is solved from `overlap` frames earlier
    (never before 0); the last is shorter; bad sizes are an InputError."""
    chunks = plan_chunks(30, 8, 4)
    assert [(c.start, c.stop, c.lead) for c in chunks] == [(0, 8, 0), (8, 16, 4), (16, 24, 12),
                                                           (24, 30, 20)]
    assert [c.name for c in chunks][:2] == ["chunk_00000.nut", "chunk_00001.nut"]
    assert plan_chunks(5, 8, 6)[0].frames == 5
    for args in ((0, 8, 4), (30, 0, 4), (30, 8, -1)):
        with pytest.raises(InputError):
            plan_chunks(*args)


@pytest.mark.slow
def test_render_matches_serial_and_keeps_the_sound(film, archive):
    """Rendered in 4 chunks on 2 processes, decoded: every frame (seams included) within 0.03 dB
    of the serial compensation in the camera's view, the projector's size and the film's rate,
    the compensation's gain over geometry only kept, and the tone's packets unchanged."""
    import av

    result, frames = archive
    info = film["info"]
    assert result.chunks == 4 and result.rendered == [0, 1, 2, 3] and result.resumed == []
    assert len(frames) == info.n_frames == 30
    assert all(f.shape == (PROJECTOR[1], PROJECTOR[0], 3) for f in frames)
    with av.open(str(result.output)) as c:
        assert c.streams.video[0].average_rate == info.fps == 24
    worst, gain = archive_figures(film, frames)
    assert worst.max() <= ACCURACY * MEASURED_ARCHIVE["off_serial"], \
        f"frame {worst.argmax()}: {worst.max():.3f} dB from serial"
    # the compensation survives, every frame
    assert gain.min() >= EFFECT * MEASURED_ARCHIVE["gain"], gain
    _same_audio(_audio_packets(film["path"]), _audio_packets(result.output))


@pytest.mark.slow
def test_render_on_dask_local_cluster(film, archive):
    """Two Dask worker processes (each its own device) render the same frames as local
    processes, and report their chunks from two processes."""
    import distributed

    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        out = film["root"] / "dask.mkv"
        result = render(film["setup"], film["path"], out, quality="archive",
                        scheduler=cluster.scheduler_address, chunk_frames=CHUNK, overlap=OVERLAP,
                        keep_work=True, work=film["root"] / "dask_work")
        manifest = json.loads((result.work / "manifest.json").read_text())
    assert result.rendered == [0, 1, 2, 3]
    assert {e["pid"] for e in manifest["chunks"].values()} - {os.getpid()}   # not in here
    frames, local = list(decode_rgb(out)), archive[1]
    assert len(frames) == len(local)
    diff = max(int(np.abs(a.astype(int) - b).max()) for a, b in zip(frames, local, strict=True))
    assert diff <= 1, f"Dask and local renders differ by {diff} codes"


KILL_SCRIPT = """
import os, signal, sys
from rtdefocus.film import render

def progress(done, total):
    if done >= 2 * int(sys.argv[4]):
        os.kill(os.getpid(), signal.SIGKILL)      # the render dies between two chunks

if __name__ == "__main__":
    render(sys.argv[1], sys.argv[2], sys.argv[3], quality="archive", workers=1,
           chunk_frames=int(sys.argv[4]), overlap=4, keep_work=True, progress=progress)
"""


@pytest.mark.slow
def test_render_killed_resumes_without_redoing_chunks(film, archive, tmp_path):
    """A render SIGKILLed after two chunks, started again, renders only the chunks that were
    not finished (the finished files untouched) and writes the same output as an uninterrupted
    render."""
    script = tmp_path / "kill.py"
    script.write_text(KILL_SCRIPT)
    out = tmp_path / "out.mkv"
    chunk = 6                                   # 5 chunks
    proc = subprocess.run([sys.executable, str(script), str(film["setup"]), str(film["path"]),
                           str(out), str(chunk)], capture_output=True, text=True, timeout=240)
    assert proc.returncode == -9, proc.stderr[-2000:]
    assert not out.exists()
    (work,) = [p for p in (tmp_path / "out.mkv.render").iterdir() if p.is_dir()]
    manifest = json.loads((work / "manifest.json").read_text())
    assert len(manifest["chunks"]) == 2
    # the orphaned worker process ends (its parent is gone) before the render starts again
    pids = {e["pid"] for e in manifest["chunks"].values()}
    deadline = time.monotonic() + 120
    while any(Path(f"/proc/{p}").exists() for p in pids) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not any(Path(f"/proc/{p}").exists() for p in pids), "a worker outlived its render"
    finished = {int(k) for k in manifest["chunks"]}
    mtimes = {k: (work / f"chunk_{k:05d}.nut").stat().st_mtime_ns for k in finished}

    result = render(film["setup"], film["path"], out, quality="archive", workers=0,
                    chunk_frames=chunk, overlap=4, keep_work=True)
    assert finished <= set(result.resumed)
    assert sorted(result.resumed + result.rendered) == [0, 1, 2, 3, 4] and result.rendered
    assert {k: (work / f"chunk_{k:05d}.nut").stat().st_mtime_ns for k in finished} == mtimes
    # the same output as one uninterrupted render with the same chunks
    whole = render(film["setup"], film["path"], tmp_path / "whole.mkv", quality="archive",
                   workers=0, chunk_frames=chunk, overlap=4)
    assert whole.resumed == [] and not whole.work.exists()      # its chunks cleaned up
    a, b = list(decode_rgb(out)), list(decode_rgb(whole.output))
    assert len(a) == len(b) == 30 and all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    _same_audio(_audio_packets(out), _audio_packets(whole.output), tol=0.0)


@pytest.mark.slow
def test_cli_default_quality_keeps_the_compensation(tmp_path):
    """`rtdefocus render` at the default quality (H.264 4:4:4, crf 4) on the 800x600 corner of
    `eval --video` (smaller set-ups blur less and score far above 40 dB, where any codec's error
    dominates): the camera's view of every decoded frame, still and panning, within 0.27 dB of
    the uncompressed compensation's and ~5 dB above geometry only; the tone's packets exact."""
    db, frames, exact = default_quality_views(tmp_path)
    for i, d in enumerate(db):
        assert d["exact"] - d["coded"] <= ACCURACY * MEASURED_DEFAULT["codec_loss"], (i, d)
        assert d["coded"] - d["geometry"] >= EFFECT * MEASURED_DEFAULT["gain"], (i, d)
        assert not np.array_equal(frames[i], exact[i])          # it is a lossy encoding


def default_quality_views(root: Path):
    """`rtdefocus render` at the default quality of a still frame and a pan at 800x600 (see
    the test): per frame the camera-view PSNR (dB) of the uncompressed compensation
    (``exact``), the decoded one (``coded``) and geometry only; the decoded frames; the exact
    ones. Checks the tone's packets on the way."""
    from rtdefocus import cli
    from rtdefocus.sim import oracle_calibration
    from rtdefocus.study.eval_video import Segment, make_clip
    from rtdefocus.study.scores import camera_view, psnr, rect_mask

    size, camera = (800, 600), (1280, 960)
    procam = rd.sim.VirtualProCam("cubicle", projector_size=size, camera_size=camera, noise=0.0)
    calib = oracle_calibration(procam)
    calib.save(root / "setup.npz")
    clip = [f for _, f in make_clip(size, (Segment("still", "still", 1),
                                           Segment("pan", "pan", 2, 8.0)))]
    write_film(root / "film.mp4", clip, fps=25)
    out = root / "out.mp4"
    code = cli.main(["-q", "render", str(root / "setup.npz"), str(root / "film.mp4"),
                     "-o", str(out), "--workers", "0"])
    assert code == 0, "rtdefocus render failed"
    frames = list(decode_rgb(out))
    _same_audio(_audio_packets(root / "film.mp4"), _audio_packets(out), tol=1e-9)
    info = probe(root / "film.mp4")
    comp = rd.Compensator(calib)
    mask = rect_mask(calib.display_rect(size), (camera[1], camera[0]))
    db, exact = [], []
    for i, image in enumerate(read_frames(info, 0, info.n_frames)):
        exact.append(comp.compensate(image, iterations=40))
        ref = camera_view(procam, calib, comp.warp(image), sharp=True)
        db.append({k: psnr(camera_view(procam, calib, f), ref, mask)
                   for k, f in (("exact", exact[-1]), ("coded", frames[i]),
                                ("geometry", comp.warp(image)))})
    return db, frames, exact


@pytest.mark.parametrize("case", ["no film", "not a video", "no setup", "output folder",
                                  "container"])
def test_bad_input_is_one_line_naming_the_fix(film, tmp_path, capsys, case):
    from rtdefocus import cli

    text = tmp_path / "notes.mp4"
    text.write_text("not a film")
    args = {"no film": [film["setup"], tmp_path / "missing.mp4", tmp_path / "o.mp4"],
            "not a video": [film["setup"], text, tmp_path / "o.mp4"],
            "no setup": [tmp_path / "missing.npz", film["path"], tmp_path / "o.mp4"],
            "output folder": [film["setup"], film["path"], Path("/proc/o.mp4")],
            "container": [film["setup"], film["path"], tmp_path / "o.mp4", "--quality",
                          "archive"]}[case]
    argv = ["-q", "render", *map(str, args[:2]), "-o", str(args[2]), *map(str, args[3:])]
    assert cli.main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("rtdefocus render: error:"), err
    expect = {"no film": ("no film at", "path of a video"),
              "not a video": ("cannot open", "convert"),
              "no setup": ("does not exist", "calibrate"),
              "output folder": ("not writable", "-o"),
              "container": (".mkv", "rename")}[case]
    assert all(e in err for e in expect), err


def test_silent_film_of_another_size_fills_the_projector(film, tmp_path):
    """A film without sound, of another size and rate, in one process: every frame out at the
    projector's size, at the film's rate, no audio stream; finished chunks cleaned up."""
    import av

    rng = np.random.default_rng(1)
    src = tmp_path / "silent.mkv"
    write_film(src, [rng.integers(0, 256, (50, 70, 3), dtype=np.uint8) for _ in range(5)], fps=25,
               tone_hz=None)
    result = render(film["setup"], src, tmp_path / "out.mov", workers=0, chunk_frames=2)
    assert result.chunks == 3 and not result.work.exists()
    with av.open(str(result.output)) as c:
        assert not c.streams.audio and c.streams.video[0].average_rate == 25
    frames = list(decode_rgb(result.output))
    assert len(frames) == 5 and all(f.shape == (PROJECTOR[1], PROJECTOR[0], 3) for f in frames)
