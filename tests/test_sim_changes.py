"""Set-ups that change during a run: bump, set_light, refocus, with the ground truth following."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rtdefocus import sim
from rtdefocus.errors import InputError

SIZES = {"projector_size": (320, 240), "camera_size": (480, 360)}


def make(preset="cubicle", **kw):
    return sim.VirtualProCam(preset, **SIZES, **kw)


def apply_h(H, x, y):
    p = H @ np.array([x, y, 1.0])
    return p[:2] / p[2]


def dot_centroid(pc, x, y, half=2):
    """Camera centroid (x, y) of a small white square at projector (x, y), sharp and noise-free."""
    wp, hp = pc.projector_size
    pat = np.zeros((hp, wp, 3), np.uint8)
    pat[y - half:y + half + 1, x - half:x + half + 1] = 255
    diff = (pc.capture(pat, sharp=True).astype(np.float64)
            - pc.capture(np.zeros_like(pat), sharp=True).astype(np.float64)).sum(axis=2)
    diff = np.clip(diff, 0.0, None)
    yy, xx = np.mgrid[:diff.shape[0], :diff.shape[1]]
    return np.array([(diff * xx).sum(), (diff * yy).sum()]) / diff.sum()


def frames(pc):
    """A checker and a black frame, as the camera sees them (noise and blur included)."""
    pat = sim.test_pattern("checker", pc.projector_size)
    return pc.capture(pat), pc.capture(np.zeros_like(pat))


def test_rebuild_without_change_is_bit_identical():
    """Rebuilding every stage of an unchanged set-up reproduces its captures and truth exactly."""
    a, b = make(seed=3), make(seed=3)
    b._rebuild(lambda: None, projector=True, camera=True)
    for fa, fb in zip(frames(a), frames(b), strict=True):
        np.testing.assert_array_equal(fa, fb)
    for name in ("H_cam_from_proj", "radius_rgb", "albedo_proj", "ambient_proj", "folds_cam"):
        np.testing.assert_array_equal(getattr(a.truth, name), getattr(b.truth, name))
    # Zero-size changes are no changes.
    b.bump(projector_yaw_deg=0.0, projector_shift_px=0, camera_shift_px=(0, 0))
    b.refocus(1.0)
    np.testing.assert_array_equal(frames(a)[0], frames(b)[0])
    assert [k for k, _ in b.changes] == ["bump", "refocus"]


@pytest.mark.parametrize("preset", ["cubicle", "tilted", "u_cubicle"])
def test_projector_shift_moves_the_picture_and_the_truth_follows(preset):
    pc = make(preset)
    x, y = 70, 90                                       # on the leftmost wall, away from folds
    H0 = pc.truth.H_cam_from_proj[pc.truth.plane_map[y, x]].copy()
    before = dot_centroid(pc, x, y)
    assert np.linalg.norm(before - apply_h(H0, x, y)) < 0.3
    pc.bump(projector_shift_px=3.0)
    H1 = pc.truth.H_cam_from_proj[pc.truth.plane_map[y, x]]
    after = dot_centroid(pc, x, y)
    # The truth's homography says where the dot now is ...
    assert np.linalg.norm(after - apply_h(H1, x, y)) < 0.3
    # ... and the physics: the dot moved by about 3 projector px through the old homography
    # (exactly at the depth of the frame's centre; this wall is a little nearer or farther).
    expect = apply_h(H0, x + 3.0, y) - apply_h(H0, x, y)
    moved = after - before
    assert np.linalg.norm(moved) > 2.0
    assert np.linalg.norm(moved - expect) < 0.15 * np.linalg.norm(expect) + 0.2, (moved, expect)
    # The oracle calibration is the truth re-measured.
    calib = sim.oracle_calibration(pc)
    np.testing.assert_allclose(calib.H_cam_from_proj, pc.truth.H_cam_from_proj)


def test_projector_yaw_turns_the_picture():
    pc = make()
    x, y = 80, 120
    H0 = pc.truth.H_cam_from_proj[0].copy()
    radius0 = pc.truth.radius_map.copy()
    before = dot_centroid(pc, x, y)
    pc.bump(projector_yaw_deg=0.3)
    after = dot_centroid(pc, x, y)
    assert np.linalg.norm(after - apply_h(pc.truth.H_cam_from_proj[0], x, y)) < 0.3
    # A turn of a moves the picture by about f tan(a) projector px to the right.
    shift = pc.K_proj[0, 0] * math.tan(math.radians(0.3))
    expect = apply_h(H0, x + shift, y) - apply_h(H0, x, y)
    assert np.linalg.norm((after - before) - expect) < 0.2 * np.linalg.norm(expect), (after - before, expect)
    # The walls did not move but the projector sees them at new depths: new blur radii.
    assert 1e-4 < np.abs(pc.truth.radius_map - radius0).max() < 0.5


def test_camera_shift_moves_only_the_camera_view():
    pc = make()
    radius0, albedo0 = pc.truth.radius_map.copy(), pc.truth.albedo_proj.copy()
    H0 = pc.truth.H_cam_from_proj.copy()
    # The projector pixel seen at the camera's centre.
    cx, cy = pc.K_cam[0, 2], pc.K_cam[1, 2]
    plane = 1 if pc.truth.fold_cam @ [cx, cy, 1.0] > 0 else 0
    px, py = apply_h(np.linalg.inv(H0[plane]), cx, cy)
    x, y = int(round(px)) + (8 if plane else -8), int(round(py))
    before = dot_centroid(pc, x, y)
    pc.bump(camera_shift_px=(4.0, -2.0))
    after = dot_centroid(pc, x, y)
    np.testing.assert_allclose(after - before, [4.0, -2.0], atol=0.15)
    assert np.linalg.norm(after - apply_h(pc.truth.H_cam_from_proj[plane], x, y)) < 0.3
    # Projector space is untouched.
    np.testing.assert_array_equal(pc.truth.radius_map, radius0)
    np.testing.assert_array_equal(pc.truth.albedo_proj, albedo0)


def test_refocus_scales_every_radius_and_the_rendered_kernels():
    # 640 px wide: radii up to ~4.8 px, large enough for a second moment to mean r².
    pc = sim.VirtualProCam("webcam_cubicle", projector_size=(640, 480), camera_size=(480, 360))
    r0, blur_scale0 = pc.truth.radius_rgb.copy(), pc.truth.blur_scale
    y, x = np.unravel_index(int(np.argmax(r0[1])), r0[1].shape)
    k0 = pc.truth.kernel_at(x, y)
    pc.refocus(1.15)
    np.testing.assert_allclose(pc.truth.radius_rgb, 1.15 * r0, rtol=1e-5)
    assert pc.truth.blur_scale == pytest.approx(1.15 * blur_scale0)
    k1 = pc.truth.kernel_at(x, y)

    def second_moment(k):
        # Of the continuous aperture: the area-sampled kernel adds a pixel's 1/12 per axis.
        h = k.shape[0] // 2
        v, u = np.mgrid[-h:h + 1, -h:h + 1]
        return float((k * (u * u + v * v)).sum()) - 1.0 / 6.0

    assert second_moment(k1) / second_moment(k0) == pytest.approx(1.15 ** 2, rel=0.02)
    # The renderer blurs with the new kernels: F P at x is the gather with truth.kernel_at(x).
    P = np.random.default_rng(2).random((480, 640, 3)).astype(np.float32)
    out = pc.defocus(P)
    for x, y in [(100, 120), (320, 240), (600, 50)]:
        k = pc.truth.kernel_at(x, y)
        h = k.shape[0] // 2
        win = P[y - h:y + h + 1, x - h:x + h + 1, 1]
        assert out[y, x, 1] == pytest.approx(float((k * win[::-1, ::-1]).sum()), abs=2e-5)


def test_set_light_raises_the_black_capture_by_the_ambient():
    pc = make(noise=0.0)
    inside = pc.truth.extra["camera_in_frame"]
    white = np.full((240, 320, 3), 255, np.uint8)
    black0 = pc.capture(np.zeros_like(white)).astype(np.float64) / 255
    white0 = pc.capture(white).astype(np.float64) / 255
    amb0 = pc.truth.ambient_proj.copy()
    pc.set_light(ambient=pc.ambient + 0.1)
    black1 = pc.capture(np.zeros_like(white)).astype(np.float64) / 255
    rise = (black1 - black0)[inside].mean()
    # The camera sees the ambient through exposure × albedo, as the truth's Γ says.
    expect = (pc.truth.ambient_proj - amb0).mean()
    assert expect == pytest.approx(0.1 * pc.exposure * 0.8, rel=0.1)
    assert rise == pytest.approx(expect, rel=0.05)
    # Exposure down 20 %: the white frame (below clipping) dims by 20 %.
    pc.set_light(exposure=0.8 * pc.exposure)
    white1 = pc.capture(white).astype(np.float64) / 255
    black2 = pc.capture(np.zeros_like(white)).astype(np.float64) / 255
    assert (white1 - black2)[inside].mean() / (white0 - black0)[inside].mean() == pytest.approx(0.8, rel=0.01)
    assert [k for k, _ in pc.changes] == ["set_light", "set_light"]


def test_bad_changes_are_refused_and_leave_the_set_up_as_it_was(monkeypatch):
    pc, twin = make(), make()
    frames(pc)
    frames(twin)
    H = pc.truth.H_cam_from_proj.copy()
    with pytest.raises(InputError, match="projector_yaw_deg"):
        pc.bump(projector_yaw_deg=12)
    with pytest.raises(InputError, match="camera_shift_px"):
        pc.bump(camera_shift_px=(1, 2, 3))
    with pytest.raises(InputError, match="refocus scale"):
        pc.refocus(0)
    with pytest.raises(InputError, match="ambient"):
        pc.set_light(ambient=-0.1)

    # A failure while rebuilding restores everything.
    def broken():
        raise RuntimeError("ray casting failed")

    monkeypatch.setattr(pc, "_build_truth", broken)
    with pytest.raises(RuntimeError):
        pc.bump(projector_shift_px=(2, 1))
    monkeypatch.undo()
    np.testing.assert_array_equal(pc.truth.H_cam_from_proj, H)
    assert pc.changes == ()
    np.testing.assert_array_equal(frames(pc)[0], frames(twin)[0])


# --------------------------------------------------------------------------- the timeline
def test_timeline_applies_events_at_their_frame_times():
    pc = make(noise=0.0)
    amb0 = pc.ambient
    tl = sim.Timeline([(0.5, "set_light", {"ambient": amb0 + 0.1}),
                       (0.2, "bump", {"camera_shift_px": (3, 0)}),
                       (0.5, "refocus", {"scale": 1.1})])
    assert [e.t for e in tl.events] == [0.2, 0.5, 0.5] and tl.next_time == 0.2
    black = np.zeros((240, 320, 3), np.uint8)
    inside = pc.truth.extra["camera_in_frame"].copy()
    H0, r0 = pc.truth.H_cam_from_proj.copy(), pc.truth.radius_map.copy()
    seen = []
    for t, cam, done in tl.play(pc, [black] * 8, fps=10):
        seen.append((t, [e.kind for e in done], cam[inside].mean()))
    kinds = {round(t, 3): k for t, k, _ in seen if k}
    assert kinds == {0.2: ["bump"], 0.5: ["set_light", "refocus"]}
    assert tl.applied == 3 and tl.next_time is None
    # The light rose on the frame at 0.5 s, not before.
    means = [m for _, _, m in seen]
    assert means[4] < means[0] + 1.0 < means[5]
    assert not np.allclose(pc.truth.H_cam_from_proj, H0)
    np.testing.assert_allclose(pc.truth.radius_map, 1.1 * r0, rtol=1e-5)
    assert [k for k, _ in pc.changes] == ["bump", "set_light", "refocus"]
    # advance() past the end applies nothing more.
    assert tl.advance(pc, 99.0) == []


def test_timeline_refuses_bad_events():
    with pytest.raises(InputError, match="unknown change 'shake'"):
        sim.Timeline([(1.0, "shake", {})])
    with pytest.raises(InputError, match="projector_yaw_deg"):
        sim.Timeline([(1.0, "bump", {"yaw": 0.3})])
    with pytest.raises(InputError, match="time must be"):
        sim.Timeline([(-1.0, "refocus", {"scale": 1.1})])
    with pytest.raises(InputError, match=r"\(t_seconds, kind, params\)"):
        sim.Timeline([(1.0, "refocus")])
