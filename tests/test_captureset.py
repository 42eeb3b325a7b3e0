"""Capture sets (a calibration's patterns and frames on disk, replayed) and the geometry from
another tool's dense correspondence map."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

import rtdefocus as rd
from rtdefocus.calib.captureset import INDEX_NAME, CaptureRecorder
from rtdefocus.errors import CaptureSetError, InputError

SIZES = {"projector_size": (200, 150), "camera_size": (320, 240)}


def _arrays(calib, path) -> dict[str, np.ndarray]:
    with np.load(calib.save(path), allow_pickle=False) as f:
        return {k: f[k] for k in f.files if k != "meta"}


@pytest.fixture(scope="module")
def saved(small_cubicle):
    """A live calibration of a small cubicle (all stages) that kept its captures. Its users
    carry ``slow`` (the calibration costs seconds); the recorder and the correspondences keep
    the module in the fast tier."""
    return small_cubicle[2], small_cubicle[1]


def _copy(saved, tmp_path):
    return shutil.copytree(saved[0], tmp_path / "copy")


@pytest.mark.slow
def test_replay_is_bit_for_bit(saved, tmp_path):
    folder, live = saved
    index = json.loads((folder / INDEX_NAME).read_text())
    assert index["projector_size"] == [200, 150] and index["camera_size"] == [320, 240]
    assert index["stages"] == ["geometry", "radiometry", "psf"]
    assert index["outcome"] == "calibrated"
    assert len(index["captures"]) == sum(live.meta["captures"].values())
    assert {r["stage"] for r in index["captures"]} >= {"geometry", "radiometry", "psf"}
    # Patterns are kept once each: far fewer files than captures.
    assert len({r["pattern"] for r in index["captures"]}) < len(index["captures"])
    again = rd.calibrate_from_captures(folder)
    a, b = _arrays(live, tmp_path / "live.npz"), _arrays(again, tmp_path / "replay.npz")
    assert sorted(a) == sorted(b) and {"psfs", "response_lut", "H_cam_from_proj"} <= set(a)
    differ = [k for k in a if a[k].dtype != b[k].dtype or not np.array_equal(a[k], b[k])]
    assert differ == [], f"arrays that differ after the replay: {differ}"


@pytest.mark.slow
def test_cli_from_captures_writes_the_same_file(saved, tmp_path):
    from rtdefocus import cli

    folder, live = saved
    out = tmp_path / "cli.npz"
    assert cli.main(["-q", "calibrate", "--from-captures", str(folder), "-o", str(out)]) == 0
    a, b = _arrays(live, tmp_path / "live.npz"), _arrays(rd.Calibration.load(out), tmp_path / "b")
    assert all(np.array_equal(a[k], b[k]) for k in a) and sorted(a) == sorted(b)


@pytest.mark.slow
def test_missing_files_are_named(saved, tmp_path):
    folder = _copy(saved, tmp_path)
    index = json.loads((folder / INDEX_NAME).read_text())
    frame, pattern = index["captures"][5]["frame"], index["captures"][-1]["pattern"]
    (folder / frame).unlink()
    (folder / pattern).unlink()
    with pytest.raises(CaptureSetError, match="incomplete: 2 of") as err:
        rd.calibrate_from_captures(folder)
    assert frame in str(err.value) and pattern in str(err.value)


@pytest.mark.slow
def test_a_set_without_its_index_is_incomplete(saved, tmp_path):
    folder = _copy(saved, tmp_path)
    (folder / INDEX_NAME).unlink()
    with pytest.raises(CaptureSetError, match="no index: the saving did not finish"):
        rd.calibrate_from_captures(folder)


@pytest.mark.slow
def test_a_damaged_frame_is_named(saved, tmp_path):
    folder = _copy(saved, tmp_path)
    index = json.loads((folder / INDEX_NAME).read_text())
    name = index["captures"][0]["frame"]
    (folder / name).write_bytes((folder / name).read_bytes()[:200])      # truncated
    with pytest.raises(CaptureSetError, match=name.replace("/", ".")):
        rd.calibrate_from_captures(folder)


@pytest.mark.slow
def test_another_pattern_is_refused(saved):
    """Other line spacing: the first line pattern differs from the one saved (captures 1 and 2
    are the black and white frames, the same for any spacing)."""
    folder, _ = saved
    with pytest.raises(CaptureSetError, match=r"capture 3 of \d+ \(stage 'geometry', "
                       r"frames/f_00002.png\) was taken of another pattern .*values differ, the "
                       r"first at projector pixel \(x=\d+, y=\d+\)"):
        rd.calibrate_from_captures(folder, line_spacing=40)


def test_recorder_keeps_out_of_other_folders(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    procam = rd.sim.VirtualProCam("flat", **SIZES)
    with pytest.raises(CaptureSetError, match="holds other files"):
        CaptureRecorder(procam, tmp_path)
    assert (tmp_path / "notes.txt").read_text() == "mine"


#: Measured by ``.venv/bin/python tools/measure_gains.py --sections correspondences``
#: (2026-12-03): the calibrated planes' round trip off the true homographies, RMS and worst
#: (projector px). Bounds 1.5x each.
MEASURED = {"rms": 0.0680, "max": 0.2515}


def true_cubicle_map():
    """The simulator's own camera -> projector map of the cubicle: (truth, map, valid)."""
    procam = rd.sim.VirtualProCam("cubicle", **SIZES)
    truth = procam.truth
    xy = truth.extra["proj_from_cam"]
    valid = np.isfinite(xy).all(axis=2) & truth.extra["camera_in_frame"]
    return truth, xy, valid


@pytest.fixture(scope="module")
def true_map():
    return true_cubicle_map()


def correspondence_errors(truth, xy, valid):
    """Every 4th projector pixel of each true plane, through the true homography into the
    camera and back through the calibrated plane's inverse: the distances (projector px), and
    the calibration."""
    calib = rd.calibrate_from_correspondences(xy, valid, SIZES["projector_size"])
    gx, gy = np.meshgrid(np.arange(0, 200, 4.0), np.arange(0, 150, 4.0))
    pts = np.stack([gx.ravel(), gy.ravel(), np.ones(gx.size)])
    true_plane = truth.plane_map[gy.astype(int).ravel(), gx.astype(int).ravel()]
    errors = []
    for p in range(2):
        sel = true_plane == p
        cam = truth.H_cam_from_proj[p] @ pts[:, sel]
        back = np.einsum("nij,jn->in", calib.H_proj_from_cam[
            calib.plane_of(pts[0, sel], pts[1, sel]).astype(int)], cam / cam[2])
        errors.append(np.linalg.norm(back[:2] / back[2] - pts[:2, sel], axis=0))
    return np.concatenate(errors), calib


def test_correspondences_recover_the_homographies(true_map):
    """The simulator's own camera -> projector map gives the true planes' homographies, within
    1.5x of the MEASURED round-trip error."""
    err, calib = correspondence_errors(*true_map)
    assert calib.n_planes == 2 and calib.meta["geometry"]["source"] == "correspondences"
    rms = np.sqrt(np.mean(err ** 2))
    assert rms <= 1.5 * MEASURED["rms"] and err.max() <= 1.5 * MEASURED["max"], (rms, err.max())


def test_correspondences_refuse_a_bad_map(true_map):
    _, xy, valid = true_map
    broken = xy.copy()
    broken[valid.nonzero()[0][0], valid.nonzero()[1][0]] = np.nan
    with pytest.raises(InputError, match="not finite at 1 valid camera pixels"):
        rd.calibrate_from_correspondences(broken, valid, (200, 150))
    with pytest.raises(InputError, match="bool mask"):
        rd.calibrate_from_correspondences(xy, valid.astype(np.uint8), (200, 150))


@pytest.mark.slow
def test_a_new_set_over_an_old_one_drops_the_old_index_first(saved, tmp_path):
    """Until the new index is written the folder must not look like a whole set."""
    folder = _copy(saved, tmp_path)
    recorder = CaptureRecorder(rd.sim.VirtualProCam("flat", **SIZES), folder)
    assert not (folder / INDEX_NAME).exists()
    with pytest.raises(CaptureSetError, match="no index: the saving did not finish"):
        rd.calibrate_from_captures(folder)
    recorder.capture(np.zeros((150, 200, 3), np.uint8))
    recorder.finish({}, ("geometry",))
    index = json.loads((folder / INDEX_NAME).read_text())
    assert len(index["captures"]) == 1 and index["exposure_control"] is True
    assert index["captures"][0]["exposure"] == pytest.approx(recorder.procam.exposure)
