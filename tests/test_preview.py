"""`play --preview`: the operator's picture (what the projector shows, scaled, with the live
figures under it), the sink that feeds it while the projector's frames stay untouched, the
player's figures in it, and the command with two windows under Xvfb."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from test_stream import PROJ, synthetic_frames, virtual_calibration

from rtdefocus.stream import ArraySource, LoopStats, Player, WindowSink
from rtdefocus.stream.preview import LINE_PX, PreviewSink, compose_preview, preview_lines


def test_compose_preview_scales_the_frame_and_writes_the_figures():
    frame = synthetic_frames(1, size=(160, 120), seed=3)[0]
    lines = ["12.0 fps   iterations 3 (mean 2.5)", "shown 10   geometry only 4 (40%)", "mode full"]
    out = compose_preview(frame, lines, (200, 220))
    assert out.shape == (220, 200, 3) and out.dtype == np.uint8
    band = LINE_PX * len(lines) + 6
    # The picture: the frame scaled to fit above the band, aspect kept (200x150), centred.
    want = cv2.resize(frame, (200, 150), interpolation=cv2.INTER_AREA)
    assert np.array_equal(out[:150], want)
    text = out[150:]
    assert text.shape[0] >= band and (text > 200).any(axis=2).sum() > 100   # white glyphs
    # Each line's glyphs sit in its own row band.
    for i in range(len(lines)):
        row = out[150 + 4 + LINE_PX * i: 150 + 4 + LINE_PX * (i + 1)]
        assert (row > 200).any(), i
    with pytest.raises(ValueError, match="too small"):
        compose_preview(frame, lines, (200, 60))


def test_preview_lines_carry_the_loop_figures():
    st = LoopStats("src", "sink")
    for n in (2, 4, 3):
        st.iterations.add(n)
        st.frame_out()
    st.geometry_frames, st.dropped, st.late = 1, 2, 1
    a, b, c = preview_lines(st, "geometry", paused=True)
    assert "iterations 3 (mean 3.0)" in a and "fps" in a
    assert "shown 3" in b and "geometry only 1 (33%)" in b and "dropped 2" in b
    assert "late 1" in b
    assert "mode geometry" in c and "PAUSED" in c


class FakeWindow:
    """A window: records what it shows, hands out queued keys."""

    def __init__(self, size):
        self.size, self.shown, self.keys, self.closed = tuple(size), [], [], False

    def show(self, frame):
        self.shown.append(np.array(frame, copy=True))

    def poll(self):
        keys, self.keys = self.keys, []
        return keys

    def wait(self, seconds):
        pass

    def close(self):
        self.closed = True

    @property
    def should_close(self):
        return self.closed


def test_preview_sink_leaves_the_projector_clean_and_follows_the_player():
    """Three moving frames through the player: the projector gets exactly the compensated
    frames (no text), the preview gets each one scaled with the player's own figures."""
    import rtdefocus as rd

    comp = rd.Compensator(virtual_calibration(), iterations=2)
    frames = synthetic_frames(3, seed=5)
    projector, preview = FakeWindow((80, 60)), FakeWindow((160, 180))   # 80x60: no direct warp
    sink = PreviewSink(WindowSink(projector), preview, rate=1e9)
    player = Player(comp, ArraySource(frames), sink, iterations=2, live=False, catch_up=False)
    sink.attach(player)
    stats = player.run()
    assert stats.frames_out == 3 and len(projector.shown) == 3 and len(preview.shown) == 3
    comp2 = rd.Compensator(virtual_calibration(), iterations=2)
    for sent, frame in zip(projector.shown, frames, strict=True):
        assert np.array_equal(sent, comp2.compensate(frame, iterations=2))
    last = preview.shown[-1]
    band = LINE_PX * 3 + 6
    scale = min(160 / PROJ[0], (180 - band) / PROJ[1])
    tw, th = round(PROJ[0] * scale), round(PROJ[1] * scale)
    want = cv2.resize(projector.shown[-1], (tw, th), interpolation=cv2.INTER_AREA)
    x0 = (160 - tw) // 2
    assert np.array_equal(last[:th, x0:x0 + tw], want)
    assert preview_lines(stats)[1].startswith("shown 3   geometry only 0")


def test_preview_sink_rate_keys_and_closing_the_preview():
    projector, preview = FakeWindow((64, 48)), FakeWindow((160, 150))
    sink = PreviewSink(WindowSink(projector), preview, rate=1e-3)   # at most one update
    frame = np.zeros((48, 64, 3), np.uint8)
    for i in range(4):
        sink.write(frame, i)
    assert len(projector.shown) == 4 and len(preview.shown) == 1 and sink.updates == 1
    preview.keys = ["right", "c"]
    projector.keys = ["space"]
    assert sink.poll() == ["space", "right", "c"]
    preview.keys = ["close"]                  # the operator closes the preview
    assert sink.poll() == [] and preview.closed and sink.preview is None
    sink.write(frame, 5)                      # the show goes on
    assert len(projector.shown) == 5
    sink.close()
    assert sink.inner.window is None and not projector.closed   # a window it did not open stays


# --------------------------------------------------------------------------- Xvfb
import test_window  # noqa: E402  (the Xvfb fixtures: a 320x240 virtual monitor)

xvfb, probe, display = test_window.xvfb, test_window.probe, test_window.display


@pytest.mark.timeout(120)
def test_cli_play_with_preview(display, tmp_path, monkeypatch, capsys):
    """`rtdefocus play setup.npz DIR --windowed WxH --preview 200x150`: two windows; the
    projector's shows exactly the frames play sent, the preview a scaled copy with figures;
    q in the preview ends the show."""
    from rtdefocus import cli
    from rtdefocus.gl.window import ProjectorWindow
    from rtdefocus.imageio import write_image

    setup = virtual_calibration().save(tmp_path / "setup.npz")
    write_image(tmp_path / "deck" / "1.png", synthetic_frames(1, seed=4)[0])
    shown: dict[tuple, list] = {}
    real_show, real_poll = ProjectorWindow.show, ProjectorWindow.poll

    def show(self, frame):
        real_show(self, frame)
        shown.setdefault(self.size, []).append((np.array(frame, copy=True), self.read()))

    def poll(self):                      # the operator presses q in the preview
        keys = real_poll(self)
        return keys + (["q"] if self.size == (200, 150) and shown.get((200, 150)) else [])

    monkeypatch.setattr(ProjectorWindow, "show", show)
    monkeypatch.setattr(ProjectorWindow, "poll", poll)
    rc = cli.main(["play", str(setup), str(tmp_path / "deck"), "--windowed", f"{PROJ[0]}x{PROJ[1]}",
                   "--iterations", "2", "--no-cache", "--preview", "200x150"])
    assert rc == 0, capsys.readouterr()
    projector, preview = shown[PROJ], shown[(200, 150)]
    assert all(np.array_equal(sent, seen) for sent, seen in projector), "projector shows what was sent"
    sent, seen = preview[-1]
    assert np.array_equal(sent, seen) and seen.shape == (150, 200, 3)
    th = 150 - (LINE_PX * 3 + 6)
    tw = round(PROJ[0] * th / PROJ[1])
    x0 = (200 - tw) // 2
    want = cv2.resize(projector[-1][0], (tw, th), interpolation=cv2.INTER_AREA)
    assert np.abs(seen[:th, x0:x0 + tw].astype(int) - want).max() <= 1
    assert (seen[th:] > 200).any(), "the figures are drawn"
    assert "frames out" in capsys.readouterr().out


def test_cli_preview_needs_the_window(tmp_path, capsys):
    from rtdefocus import cli
    from rtdefocus.imageio import write_image

    setup = virtual_calibration().save(tmp_path / "setup.npz")
    write_image(tmp_path / "a.png", synthetic_frames(1, seed=4)[0])
    rc = cli.main(["play", str(setup), str(tmp_path / "a.png"), "--out", str(tmp_path / "o.png"),
                   "--preview"])
    assert rc == 1 and "--preview shows the projector's window" in capsys.readouterr().err
