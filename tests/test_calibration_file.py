"""The calibration file (DESIGN.md §7): round trip, atomic writes, and one clear error for
every kind of bad file."""

from __future__ import annotations

import json
import os
import zipfile

import numpy as np
import pytest

from rtdefocus.calib.file import FORMAT_VERSION, Calibration, content_digest
from rtdefocus.errors import CalibrationFileError, InputError
from rtdefocus.planar import PlaneLayout

WP, HP = 41, 29          # small odd projector: the file logic does not depend on size


def _calibration(seed: int = 0, planes: int = 2, full: bool = True) -> Calibration:
    rng = np.random.default_rng(seed)
    H = np.stack([np.eye(3) + 0.01 * rng.standard_normal((3, 3)) for _ in range(planes)])
    H /= H[:, 2:3, 2:3]
    fold = np.array([1.0, 0.0, -20.5]) if planes == 2 else np.zeros(3)
    kw = {}
    if full:
        n, k = 6, 7
        psfs = rng.random((n, k, k)).astype(np.float32)
        psfs /= psfs.sum(axis=(1, 2), keepdims=True)
        wts = rng.random((HP, WP, 4)).astype(np.float32)
        kw = dict(
            response_lut=np.tile(np.linspace(0, 1, 256, dtype=np.float32) ** 2.2, (3, 1)),
            ambient_proj=rng.random((HP, WP, 3)).astype(np.float32) * 0.05,
            albedo_proj=rng.random((HP, WP, 3)).astype(np.float32),
            psf_points_proj=rng.random((n, 2)).astype(np.float32) * 30,
            psf_plane=rng.integers(0, planes, n).astype(np.int32),
            psfs=psfs,
            pix_idx=rng.integers(0, n, (HP, WP, 4)).astype(np.int32),
            pix_wts=wts / wts.sum(axis=2, keepdims=True),
        )
    return Calibration.with_fold(projector_size=(WP, HP), camera_size=(64, 48), H_cam_from_proj=H,
                       H_proj_from_cam=np.linalg.inv(H), fold_proj=fold, fold_cam=fold.copy(),
                       lit_polygon_cam=rng.random((6, 2)) * 40,
                       meta={"geometry": {"n_planes": planes, "rms_px": [0.03] * planes}}, **kw)


ARRAYS = ["H_cam_from_proj", "H_proj_from_cam", "folds_proj", "folds_cam", "fold_planes",
          "lit_polygon_cam",
          "response_lut", "ambient_proj", "albedo_proj", "psf_points_proj", "psf_plane", "psfs",
          "pix_idx", "pix_wts"]


@pytest.mark.parametrize("planes,full", [(2, True), (1, False)], ids=["two-planes-all-sections",
                                                                      "one-plane-geometry-only"])
def test_round_trip_is_exact(tmp_path, planes, full):
    calib = _calibration(planes=planes, full=full)
    path = calib.save(tmp_path / "setup.npz")
    back = Calibration.load(path)
    assert back.projector_size == (WP, HP) and back.camera_size == (64, 48)
    assert back.n_planes == planes and back.sections() == calib.sections()
    for name in ARRAYS:
        a, b = getattr(calib, name), getattr(back, name)
        if a is None:
            assert b is None, name
            continue
        assert b.dtype == np.asarray(a).dtype and b.shape == np.shape(a), name
        np.testing.assert_array_equal(b, a, err_msg=name)
    assert back.meta["geometry"] == calib.meta["geometry"]
    assert back.meta["loaded_from"]["path"] == str(path)
    if full:
        np.testing.assert_allclose(back.kernel_at(3, 4), calib.kernel_at(3, 4), rtol=0, atol=0)


def test_save_adds_the_suffix_and_leaves_no_temporary_files(tmp_path):
    path = _calibration().save(tmp_path / "setup")
    assert path.name == "setup.npz" and path.is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["setup.npz"]


def test_failed_save_keeps_the_old_file(tmp_path, monkeypatch):
    path = _calibration(seed=1).save(tmp_path / "setup.npz")
    before = path.read_bytes()

    def crash(fh, **arrays):
        fh.write(b"PK\x03\x04 half a file")          # something is written, then the crash
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(np, "savez_compressed", crash)
    with pytest.raises(OSError, match="disk full"):
        _calibration(seed=2).save(path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["setup.npz"], "temporary file left"
    monkeypatch.undo()
    np.testing.assert_array_equal(Calibration.load(path).H_cam_from_proj,
                                  _calibration(seed=1).H_cam_from_proj)


# --------------------------------------------------------------------------- bad files
def _rewrite(src, dst, *, meta_update=None, drop=(), **replace):
    """Copy a saved calibration with entries replaced/dropped (written with plain np.savez)."""
    with np.load(src, allow_pickle=False) as npz:
        data = {k: npz[k] for k in npz.files}
    if meta_update is not None:
        m = json.loads(str(data["meta"]))
        m.update(meta_update)
        data["meta"] = np.array(json.dumps(m))
    for k in drop:
        data.pop(k)
    data.update(replace)
    np.savez(dst, **data)
    return dst


@pytest.fixture()
def good(tmp_path):
    return _calibration().save(tmp_path / "good.npz")


def _bad_files(good, tmp):
    """name -> (path, regex the one error message must match)."""
    raw = good.read_bytes()
    out = {}
    p = tmp / "truncated.npz"
    p.write_bytes(raw[: len(raw) // 2])
    out["truncated"] = (p, "truncated or not an .npz")
    p = tmp / "random.npz"
    p.write_bytes(np.random.default_rng(0).bytes(4096))
    out["random-bytes"] = (p, "not an .npz archive")
    p = tmp / "empty.npz"
    p.write_bytes(b"")
    out["empty"] = (p, "not an .npz archive")
    p = tmp / "foreign.npz"
    np.savez(p, weights=np.zeros(3))
    out["foreign-no-meta"] = (p, "not an rtdefocus calibration")
    out["foreign-format"] = (_rewrite(good, tmp / "fmt.npz", meta_update={"format": "something-else"}),
                             "not an rtdefocus calibration")
    newer = {"format_version": FORMAT_VERSION + 1}
    out["wrong-version"] = (_rewrite(good, tmp / "ver.npz", meta_update=newer),
                            f"version {FORMAT_VERSION + 1}.*recalibrate")
    out["wrong-shape"] = (_rewrite(good, tmp / "shape.npz", H_cam_from_proj=np.zeros((2, 3, 4))),
                          r"H_cam_from_proj has shape \(2, 3, 4\)")
    out["wrong-dtype"] = (_rewrite(good, tmp / "dtype.npz", pix_idx=np.zeros((HP, WP, 4), np.float32)),
                          "pix_idx has dtype float32, expected int32")
    out["projector-size-mismatch"] = (
        _rewrite(good, tmp / "size.npz", ambient_proj=np.zeros((HP + 1, WP, 3), np.float32)),
        "ambient_proj has shape")
    out["missing-geometry"] = (_rewrite(good, tmp / "miss.npz", drop=["folds_cam"]),
                               r"geometry section is incomplete, missing \['folds_cam'\]")
    out["unknown-entry"] = (_rewrite(good, tmp / "unk.npz", roration=np.eye(3)),
                            r"unknown entries \['roration'\]")
    out["nan"] = (_rewrite(good, tmp / "nan.npz", folds_proj=np.array([[np.nan, 0.0, 1.0]])),
                  "folds_proj contains NaN")
    out["three-planes"] = (_rewrite(good, tmp / "three.npz", H_cam_from_proj=np.tile(np.eye(3), (3, 1, 1)),
                                    H_proj_from_cam=np.tile(np.eye(3), (3, 1, 1))), "3 planes")
    out["bad-meta-json"] = (_rewrite(good, tmp / "json.npz", meta=np.array("{oops")),
                            "not valid JSON")
    p = tmp / "pickle.npz"
    with np.load(good, allow_pickle=False) as npz:
        data = {k: npz[k] for k in npz.files}
    data["psf_plane"] = np.array([{"evil": "object"}, 1], dtype=object)
    np.savez(p, **data)                       # np.savez pickles object arrays
    out["pickle-carrying"] = (p, "pickled Python objects")
    out["missing"] = (tmp / "nope.npz", "does not exist")
    return out


BAD = ["truncated", "random-bytes", "empty", "foreign-no-meta", "foreign-format", "wrong-version",
       "wrong-shape", "wrong-dtype", "projector-size-mismatch", "missing-geometry", "unknown-entry",
       "nan", "three-planes", "bad-meta-json", "pickle-carrying", "missing"]


@pytest.mark.parametrize("kind", BAD)
def test_bad_file_gives_one_clear_error(good, tmp_path, kind):
    path, pattern = _bad_files(good, tmp_path)[kind]
    with pytest.raises(CalibrationFileError, match=pattern) as info:
        Calibration.load(path)
    msg = str(info.value)
    assert str(path.name) in msg, "the message names the file"
    # CalibrationFileError is also a ValueError, so generic handlers still catch it
    assert isinstance(info.value, ValueError)


def test_pickle_is_never_executed(good, tmp_path):
    class Boom:
        def __reduce__(self):
            return (os.system, ("touch " + str(tmp_path / "pwned"),))

    with np.load(good, allow_pickle=False) as npz:
        data = {k: npz[k] for k in npz.files}
    arr = np.empty(1, dtype=object)
    arr[0] = Boom()
    data["psfs"] = arr
    np.savez(tmp_path / "evil.npz", **data)
    with pytest.raises(CalibrationFileError, match="pickled"):
        Calibration.load(tmp_path / "evil.npz")
    assert not (tmp_path / "pwned").exists()


def test_validate_rejects_bad_arrays_before_writing(tmp_path):
    calib = _calibration()
    calib.H_cam_from_proj = np.zeros((2, 3, 4))
    with pytest.raises(CalibrationFileError, match="H_cam_from_proj has shape"):
        calib.save(tmp_path / "x.npz")
    assert not any(tmp_path.iterdir())


# --------------------------------------------------------------------------- integrity
DAMAGE = "damaged or was edited"


def _load_raw(path):
    with np.load(path, allow_pickle=False) as npz:
        return {k: npz[k] for k in npz.files}


def _flip_byte(arr: np.ndarray, rng) -> np.ndarray:
    raw = bytearray(np.ascontiguousarray(arr).tobytes())
    i = int(rng.integers(len(raw)))
    raw[i] ^= int(rng.integers(1, 256))           # a non-zero mask: the byte always changes
    return np.frombuffer(bytes(raw), dtype=arr.dtype).reshape(arr.shape)


def _drop_row(arr: np.ndarray, rng) -> np.ndarray:
    return np.delete(arr, int(rng.integers(arr.shape[0])), axis=0)


@pytest.fixture(scope="module")
def good_raw(tmp_path_factory):
    """One good file (all sections, two planes) and its entries, built once for the module."""
    path = _calibration().save(tmp_path_factory.mktemp("good") / "good.npz")
    return path, _load_raw(path)


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("damage", ["flip-byte", "drop-row"])
@pytest.mark.parametrize("name", ARRAYS)
def test_any_change_of_any_array_is_the_integrity_error(good_raw, tmp_path, name, damage, seed):
    _, data = good_raw
    rng = np.random.default_rng([seed, ARRAYS.index(name)])
    data = dict(data)
    data[name] = (_flip_byte if damage == "flip-byte" else _drop_row)(data[name], rng)
    path = tmp_path / "edited.npz"
    np.savez(path, **data)
    with pytest.raises(CalibrationFileError, match=DAMAGE) as info:
        Calibration.load(path)
    assert "edited.npz" in str(info.value) and "verify=False" in str(info.value)


def test_the_reported_case_a_polygon_that_lost_a_vertex(good_raw, tmp_path):
    """The issue's example: shapes stay legal ((m, 2) with any m), the display moves."""
    _, data = good_raw
    data = dict(data, lit_polygon_cam=data["lit_polygon_cam"][:-1])
    np.savez(tmp_path / "poly.npz", **data)
    with pytest.raises(CalibrationFileError, match=DAMAGE):
        Calibration.load(tmp_path / "poly.npz")
    # An expert who did it on purpose gets the file, with a warning.
    back = Calibration.load(tmp_path / "poly.npz", verify=False)
    assert back.lit_polygon_cam.shape == (5, 2)


def test_an_edited_meta_is_the_integrity_error(good_raw, tmp_path):
    path, _ = good_raw
    edited = _rewrite(path, tmp_path / "meta.npz",
                      meta_update={"geometry": {"n_planes": 2, "rms_px": [0.01, 0.01]}})
    with pytest.raises(CalibrationFileError, match=DAMAGE):
        Calibration.load(edited)


def test_verify_false_loads_an_edited_file_with_a_warning(good_raw, tmp_path, caplog):
    path, data = good_raw
    H = data["H_cam_from_proj"].copy()
    H[0, 0, 2] += 5.0                                   # a deliberate 5 px shift of plane 0
    edited = _rewrite(path, tmp_path / "shifted.npz", H_cam_from_proj=H)
    with caplog.at_level("WARNING", logger="rtdefocus.calib.file"):
        back = Calibration.load(edited, verify=False)
    np.testing.assert_array_equal(back.H_cam_from_proj, H)
    assert any("digest does not match" in r.getMessage() for r in caplog.records)
    # verify=False skips only the digest: a malformed file is still refused.
    bad = _rewrite(path, tmp_path / "bad.npz", folds_proj=np.array([[np.nan, 0.0, 1.0]]))
    with pytest.raises(CalibrationFileError, match="folds_proj contains NaN"):
        Calibration.load(bad, verify=False)


def test_a_file_without_a_digest_still_loads_with_a_note(good_raw, tmp_path, caplog):
    path, data = good_raw
    meta = json.loads(str(data["meta"]))
    del meta["sha256"]
    old = dict(data, meta=np.array(json.dumps(meta)))
    np.savez(tmp_path / "old.npz", **old)
    with caplog.at_level("INFO", logger="rtdefocus.calib.file"):
        back = Calibration.load(tmp_path / "old.npz")
    np.testing.assert_array_equal(back.psfs, data["psfs"])
    assert any("no content digest" in r.getMessage() for r in caplog.records)
    assert "sha256" not in back.meta


def test_a_loaded_and_saved_again_file_verifies(good_raw, tmp_path):
    path, _ = good_raw
    again = Calibration.load(path).save(tmp_path / "again.npz")
    assert Calibration.load(again).sections() == ["geometry", "radiometry", "psf"]


@pytest.mark.parametrize("seed", range(6))
def test_a_flipped_byte_anywhere_in_the_file_is_refused_or_harmless(good_raw, tmp_path, seed):
    """On disk the arrays are compressed: a flipped byte fails the zip CRC, the inflater or the
    digest — always one CalibrationFileError — unless it hit zip metadata that changes no
    content (then the digest proves the content is as saved)."""
    path, data = good_raw
    raw = bytearray(path.read_bytes())
    rng = np.random.default_rng(seed)
    for _ in range(40):
        b = raw.copy()
        b[int(rng.integers(len(b)))] ^= int(rng.integers(1, 256))
        (tmp_path / "flip.npz").write_bytes(bytes(b))
        try:
            back = Calibration.load(tmp_path / "flip.npz")
        except CalibrationFileError:
            continue
        for name in ARRAYS:
            np.testing.assert_array_equal(getattr(back, name), data[name], err_msg=name)


def test_an_array_header_cut_short_is_the_damaged_file_error(good_raw, tmp_path):
    """An array whose .npy header no longer parses (a flipped byte inside the compressed
    member reaches the header before the CRC is checked) is one CalibrationFileError, not
    numpy's tokenizer error. (Found by the randomised flip test above on a fresh clone.)"""
    path, _ = good_raw
    bad = tmp_path / "bad.npz"
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(bad, "w") as dst:
        for info in src.infolist():
            body = src.read(info)
            if info.filename == "H_cam_from_proj.npy":
                start = body.index(b"{")
                body = body[:start + 20] + b"\xfe" + b" " * (body.index(b"\n") - start - 21) + \
                    body[body.index(b"\n"):]
            dst.writestr(info.filename, body)
    with pytest.raises(CalibrationFileError, match="damaged"):
        Calibration.load(bad)


# --------------------------------------------------------------------------- paths
@pytest.mark.parametrize("saved_as,loaded_as", [("setup", "setup"), ("setup", "setup.npz"),
                                                ("setup.npz", "setup"),
                                                ("setup.npz", "setup.npz"),
                                                ("setup.v2", "setup.v2")])
def test_save_and_load_agree_on_both_spellings(tmp_path, saved_as, loaded_as):
    calib = _calibration(seed=3)
    written = calib.save(tmp_path / saved_as)
    assert written.is_file() and written.suffix == ".npz"
    assert sorted(p.name for p in tmp_path.iterdir()) == [written.name]
    back = Calibration.load(tmp_path / loaded_as)
    np.testing.assert_array_equal(back.H_cam_from_proj, calib.H_cam_from_proj)
    assert back.meta["loaded_from"]["path"] == str(written)


def test_load_reads_a_file_named_without_npz_when_only_it_exists(tmp_path):
    written = _calibration(seed=4).save(tmp_path / "x.npz")
    renamed = written.rename(tmp_path / "calibration.dat")
    assert Calibration.load(renamed).meta["loaded_from"]["path"] == str(renamed)


def test_missing_file_names_both_spellings(tmp_path):
    with pytest.raises(CalibrationFileError, match=r"'.*nothing' nor '.*nothing\.npz' does not "
                                                   r"exist"):
        Calibration.load(tmp_path / "nothing")


# --------------------------------------------------------------------------- planes and versions
def _three_planes() -> Calibration:
    """A U of three planes (folds at x = 12.5 and 27.5), geometry only."""
    H = np.stack([np.eye(3)] * 3)
    folds = np.array([[1.0, 0.0, -12.5], [1.0, 0.0, -27.5]])
    return Calibration(projector_size=(WP, HP), camera_size=(64, 48), H_cam_from_proj=H,
                       H_proj_from_cam=H.copy(), folds_proj=folds, folds_cam=folds.copy(),
                       fold_planes=np.array([[0, 1], [1, 2]], np.int32),
                       lit_polygon_cam=np.array([[0.0, 0], [40, 0], [40, 28], [0, 28]]))


def test_three_planes_round_trip(tmp_path):
    calib = _three_planes()
    back = Calibration.load(calib.save(tmp_path / "u.npz"))
    assert back.n_planes == 3 and back.layout == calib.layout
    assert back.plane_of(np.array([5.0, 20.0, 35.0]), np.array([3.0, 3.0, 3.0])).tolist() == [0, 1, 2]
    with pytest.raises(InputError, match="calib.layout"):
        _ = back.fold_proj


def test_folds_that_do_not_describe_the_planes_are_a_clear_error(tmp_path):
    path = _three_planes().save(tmp_path / "u.npz")
    with np.load(path, allow_pickle=False) as npz:
        data = {k: npz[k] for k in npz.files}
    meta = json.loads(str(data.pop("meta")))
    data["fold_planes"] = np.array([[0, 1], [1, 5]], np.int32)      # no plane 5
    meta["sha256"] = content_digest(meta, data)                      # a consistent file
    np.savez(tmp_path / "bad.npz", meta=np.array(json.dumps(meta)), **data)
    with pytest.raises(CalibrationFileError, match="folds do not describe 3 planes.*recalibrate"):
        Calibration.load(tmp_path / "bad.npz")


@pytest.mark.parametrize("planes", [1, 2])
def test_a_format_2_file_still_loads(tmp_path, planes):
    """Format 2 stored one fold line (zeros for one plane): it loads as the same layout."""
    calib = _calibration(planes=planes)
    path = calib.save(tmp_path / "v3.npz")
    with np.load(path, allow_pickle=False) as npz:
        data = {k: npz[k] for k in npz.files}
    meta = json.loads(str(data.pop("meta")))
    meta["format_version"] = 2
    for name in ("folds_proj", "folds_cam"):
        folds = data.pop(name)
        data[name[:4] + name[5:]] = folds[0] if len(folds) else np.zeros(3)
    del data["fold_planes"]
    meta["sha256"] = content_digest(meta, data)
    np.savez(tmp_path / "v2.npz", meta=np.array(json.dumps(meta)), **data)
    back = Calibration.load(tmp_path / "v2.npz")
    assert back.n_planes == planes and back.layout == calib.layout
    np.testing.assert_array_equal(back.fold_proj, calib.fold_proj)
    ys, xs = np.mgrid[0:HP, 0:WP]
    np.testing.assert_array_equal(back.plane_of(xs, ys), calib.plane_of(xs, ys))
    assert PlaneLayout.from_fold(calib.fold_proj, planes) == back.layout
