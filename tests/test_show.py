"""What a show needs: PDF decks as slides, videos decoded by PyAV and shown by their audio clock,
playlists (a folder of images, PDFs and videos) with --loop and a black end, content placement
(--fit, --margin), and one-line errors for a PDF that does not open and a video that does not
decode. Screen and window capture under Xvfb are in test_capture.py."""

from __future__ import annotations

import time

import av  # the show extra, part of the test extra
import numpy as np
import pytest
from test_stream import PROJ, RecordingSink, max_abs, synthetic_frames, virtual_calibration

import rtdefocus as rd
from rtdefocus import cli
from rtdefocus.errors import InputError
from rtdefocus.imageio import read_image, write_image
from rtdefocus.stream import (
    ImageSequenceSink,
    NullSink,
    Placement,
    Player,
    Show,
    SlidesSource,
    open_source,
    playlist,
)
from rtdefocus.stream.audio import AudioOutput, WallClock, open_audio_output

#: Page colours of the generated deck (RGB).
PAGE_COLOURS = [(220, 30, 30), (30, 160, 40), (40, 60, 210)]


@pytest.fixture(scope="module")
def calib():
    return virtual_calibration()


@pytest.fixture(scope="module")
def comp(calib):
    return rd.Compensator(calib)


def make_pdf(path, colours=PAGE_COLOURS, inches=(4.0, 3.0)):
    """A deck whose page i is filled with colours[i] and carries a white square at its centre."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.backends.backend_pdf import PdfPages

    with PdfPages(path) as pdf:
        for c in colours:
            fig = plt.figure(figsize=inches)
            fig.patch.set_facecolor(np.array(c) / 255)
            fig.add_artist(plt.Rectangle((0.4, 0.4), 0.2, 0.2, color="white",
                                         transform=fig.transFigure))
            pdf.savefig(fig, facecolor=fig.get_facecolor())
            plt.close(fig)
    return path


def make_video(path, seconds=2.0, fps=30, size=(32, 24), rate=48000, flash_every=1.0,
               sound_seconds=None):
    """An MP4 (MPEG-4 video, AAC sound) whose frame at each multiple of ``flash_every`` seconds
    is white (a flash) and whose sound is a 1 kHz beep for 50 ms from that same instant
    (silence otherwise); the other frames are dark with a moving red column. The sound stops
    after ``sound_seconds`` (default: with the picture)."""
    sound_end = int((seconds if sound_seconds is None else sound_seconds) * rate)
    w, h = size
    n = int(round(seconds * fps))
    per_flash = int(round(flash_every * fps))
    with av.open(str(path), "w") as c:
        vs = c.add_stream("mpeg4", rate=fps)
        vs.width, vs.height, vs.pix_fmt, vs.bit_rate = w, h, "yuv420p", 400_000
        aus = c.add_stream("aac", rate=rate)
        aus.layout = "stereo"
        block, done = 1024, 0
        for i in range(n):
            img = np.full((h, w, 3), 40, np.uint8)
            if i % per_flash == 0:
                img[:] = 255
            img[:, i % w] = (200, 0, 0)
            vf = av.VideoFrame.from_ndarray(img, format="rgb24")
            vf.pts = i
            for p in vs.encode(vf):
                c.mux(p)
            while done < min((i + 1) * rate // fps, sound_end):
                t = (done + np.arange(block)) / rate
                beep = ((t % flash_every) < 0.05).astype(np.float32)
                x = (0.5 * beep * np.sin(2 * np.pi * 1000 * t)).astype(np.float32)
                af = av.AudioFrame.from_ndarray(np.stack([x, x]), format="fltp", layout="stereo")
                af.sample_rate, af.pts = rate, done
                for p in aus.encode(af):
                    c.mux(p)
                done += block
        for s in (vs, aus):
            for p in s.encode(None):
                c.mux(p)
    return path


class FakeSoundCard(AudioOutput):
    """A sound card without a device: it consumes samples in blocks of ``block`` (as a callback
    does) only when time passes, and time passes only through :meth:`sleep` (the source
    waiting) and :meth:`advance` (the test's stand-in for the solver's time). Its position is
    what it consumed, so the clock is the sound's and the run is deterministic."""

    rate, channels = 48000, 2

    def __init__(self, block=256):
        super().__init__()
        self.block = block
        self.heard: list[np.ndarray] = []
        self._debt = 0.0

    def advance(self, seconds: float) -> None:
        self._debt += seconds * self.rate
        while self._debt >= self.block:
            self._debt -= self.block
            buf = np.zeros((self.block, self.channels), np.float32)
            got = self._take(self.block, buf)
            if got < self.block and self._ended:
                with self._lock:
                    self._played += self.block - got     # silence after the end
            self.heard.append(buf)

    def sleep(self, seconds: float) -> None:
        self.advance(max(seconds, 1.0 / self.rate * self.block))

    def position(self) -> float:
        with self._lock:
            return self._played / self.rate


# --------------------------------------------------------------------------- PDF
def test_pdf_pages_are_slides_at_the_projectors_size(tmp_path):
    pdf = make_pdf(tmp_path / "deck.pdf")
    with open_source(pdf, projector_size=(200, 150)) as src:
        assert isinstance(src, SlidesSource) and src.still and src.n_frames == 3
        assert [src.name(i) for i in range(3)] == ["deck.pdf p1", "deck.pdf p2", "deck.pdf p3"]
        for i, colour in enumerate(PAGE_COLOURS):
            page = src.load(i)
            assert page.shape == (150, 200, 3), "a 4:3 page fills a 4:3 projector"
            assert np.abs(page[10, 10].astype(int) - colour).max() <= 3, (i, page[10, 10])
            assert page[75, 100].min() >= 250, "the white square sits at the page's centre"
    with open_source(pdf, projector_size=(300, 100)) as src:    # a wide projector: fitted
        assert src.load(0).shape[:2] in ((100, 133), (100, 134))


def test_cli_play_pdf_deck_is_cached_like_images(tmp_path, calib, capsys):
    """`play setup.npz deck.pdf --out out/` writes one compensated frame per page, each the
    refined still of the rendered page; the second show comes from the cache."""
    setup = calib.save(tmp_path / "setup.npz")
    pdf = make_pdf(tmp_path / "deck.pdf")
    args = ["-q", "play", str(setup), str(pdf), "--out", str(tmp_path / "o1"), "--cache",
            str(tmp_path / "cache"), "--iterations", "4"]
    assert cli.main(args) == 0
    outs = sorted((tmp_path / "o1").glob("frame_*.png"))
    assert [p.name for p in outs] == [f"frame_00000{i}.png" for i in range(3)]
    assert len(list((tmp_path / "cache").rglob("*.png"))) == 3
    c = rd.Compensator(calib)
    with SlidesSource(pdf, size=PROJ) as deck:
        for i, path in enumerate(outs):
            expect = c.compensate(deck.load(i), iterations=4, warm_start=False)
            assert max_abs(read_image(path), expect) <= 1, i
    args[5] = str(tmp_path / "o2")
    assert cli.main(args) == 0
    assert "3 frames out" in capsys.readouterr().out
    for i in range(3):
        name = f"frame_00000{i}.png"
        assert np.array_equal(read_image(tmp_path / "o1" / name), read_image(tmp_path / "o2" / name))


def test_pdf_slides_follow_the_keys(tmp_path, comp):
    pdf = make_pdf(tmp_path / "deck.pdf")
    sink = RecordingSink(realtime=True, keys=["right", "right", "right", "left", "q"])
    with SlidesSource(pdf, size=PROJ) as src:
        pages = [src.load(i) for i in range(3)]
        Player(comp, src, sink, iterations=2).run()
    assert sink.indices == [0, 1, 2, 2, 1]          # stops at the last page, goes back
    for idx, frame in zip(sink.indices, sink.frames, strict=True):
        assert max_abs(frame, comp.compensate(pages[idx], iterations=2, warm_start=False)) <= 1


def test_pdf_that_does_not_open_is_a_one_line_error(tmp_path, calib, capsys):
    bad = tmp_path / "talk.pdf"
    bad.write_bytes(b"%PDF-1.7\n" + bytes(range(256)) * 8)
    with pytest.raises(InputError, match="cannot open .* as a PDF"):
        SlidesSource(bad)
    setup = calib.save(tmp_path / "setup.npz")
    assert cli.main(["play", str(setup), str(bad), "--out", "null"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Export" in err and "talk.pdf" in err


def test_pdf_without_pypdfium2_names_it(tmp_path, monkeypatch):
    pdf = make_pdf(tmp_path / "deck.pdf", colours=PAGE_COLOURS[:1])
    monkeypatch.setitem(__import__("sys").modules, "pypdfium2", None)
    with pytest.raises(InputError, match=r"pip install pypdfium2"):
        SlidesSource(pdf)


# --------------------------------------------------------------------------- video + sound
@pytest.fixture(scope="module")
def film(tmp_path_factory):
    return make_video(tmp_path_factory.mktemp("film") / "film.mp4", seconds=30.0)


def _play_by_the_sound(comp, film, solve_ms, seed):
    """Plays ``film`` through the Player with a fake sound card; each frame's compensation takes
    ``solve_ms`` (a range) of the card's time. Returns, per shown frame, (the source's clock
    when read, the sound played when shown, pts, flash?), the card, and the source's skip
    count. The film's sound starts at 0 s, so the sound played (what the card consumed) is the
    true audio position, independent of the source's own bookkeeping."""
    from rtdefocus.stream.avvideo import AvVideoSource

    card = FakeSoundCard()
    rng = np.random.default_rng(seed)
    rows = []
    src = AvVideoSource(film, clock=card)

    class Screen(RecordingSink):
        def write(self, frame, index):
            card.advance(rng.uniform(*solve_ms) / 1e3)        # the solve and the present
            rows.append((src.last_clock, card.position(), src.last_pts, frame.mean() > 150))

    with src:
        assert src.live and src.fps == 30
        Player(comp, src, Screen(), iterations=1, threads=False).run()
    return np.array(rows, float), card, src.skipped


def _beep_onsets(card) -> np.ndarray:
    heard = np.abs(np.concatenate(card.heard)[:, 0]) > 0.05
    loud = np.flatnonzero(heard)
    return loud[np.r_[True, np.diff(loud) > card.rate // 10]] / card.rate


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_video_and_sound_stay_within_40ms_over_30s(comp, film):
    """A 30 s film with a flash and a beep each second, played by the sound's clock with a
    solver that takes 0-30 ms per frame: every frame is shown within 40 ms of the sound
    position, and every flash within 40 ms of its beep as the card played it."""
    rows, card, skipped = _play_by_the_sound(comp, film, (0.0, 30.0), seed=1)
    read_at, shown_at, pts, flash = rows.T
    assert len(rows) >= 880 and shown_at[-1] >= 29.9
    lag = shown_at - pts
    assert lag.min() >= 0.0 and lag.max() <= 0.040, (lag.min(), lag.max())
    onsets = _beep_onsets(card)
    assert len(onsets) == 30 and np.abs(onsets - np.arange(30)).max() < 0.002, onsets[:5]
    flashes = shown_at[flash > 0]
    assert len(flashes) >= 28
    gap = np.abs(flashes[:, None] - onsets[None, :]).min(axis=1)
    assert gap.max() <= 0.040, gap.max()


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_a_slow_solver_skips_frames_to_follow_the_sound(comp, film):
    """45-60 ms per frame (slower than the 33 ms period): frames are skipped, and each frame
    read is the one the clock is in at that moment (never an old one), to the end of the film:
    the picture does not fall behind the sound."""
    rows, card, skipped = _play_by_the_sound(comp, film, (45.0, 60.0), seed=2)
    read_at, shown_at, pts, _ = rows.T
    assert skipped > 300 and len(rows) + skipped == 900
    behind = read_at - pts
    assert behind.min() >= 0.0 and behind.max() < 1 / 30 + 0.006, behind.max()
    assert shown_at[-1] >= 29.9 and pts[-1] >= 29.9


def test_pause_stops_the_sound_and_resumes_where_it_was(tmp_path, comp):
    """Space pauses the picture and the sound's clock with it; after the second space the film
    goes on from the held frame (nothing skipped), and quitting while paused releases the
    clock. Time passes 10 ms per turn of the loop (each key poll)."""
    from rtdefocus.stream.avvideo import AvVideoSource

    class PausableCard(FakeSoundCard):
        paused = False

        def __init__(self):
            super().__init__()
            self.calls = []

        def set_paused(self, paused):
            self.calls.append(paused)
            self.paused = paused

        def advance(self, seconds):
            if not self.paused:
                super().advance(seconds)

    card = PausableCard()
    script = [[]] * 8 + [["space"]] + [[]] * 20 + [["space"]] + [[]] * 10 + [["space"], ["q"]]

    pts = []

    class Screen(RecordingSink):
        def poll(self):
            card.advance(0.010)
            return script.pop(0) if script else ["q"]

        def write(self, frame, index):
            super().write(frame, index)
            pts.append(round(src.last_pts * 30))        # the film's own frame number

    sink = Screen(realtime=True, keys=[])
    src = AvVideoSource(make_video(tmp_path / "v.mp4", seconds=2.0), clock=card)
    with src:
        Player(comp, src, sink, iterations=1, threads=False).run()
    assert card.calls == [True, False, True, False]       # the last: released on quit
    shown = list(dict.fromkeys(pts))                       # each frame once, in order
    assert shown == list(range(len(shown))), f"a frame was skipped around the pause: {shown}"
    assert 3 <= len(shown) < 20 and src.skipped == 0


def test_a_sound_track_that_ends_early_hands_over_to_the_wall_clock(tmp_path, comp, caplog):
    """The sound stops after 1 s of a 12 s film: the picture goes on to the end (by the wall
    clock, said once in the log) instead of waiting for sound that never comes."""
    from rtdefocus.stream.avvideo import AvVideoSource

    card = FakeSoundCard()

    class Screen(RecordingSink):
        def write(self, frame, index):
            super().write(frame, index)
            card.advance(0.005)

    src = AvVideoSource(make_video(tmp_path / "v.mp4", seconds=12.0, sound_seconds=1.0), clock=card)
    sink = Screen()
    with src, caplog.at_level("WARNING", logger="rtdefocus.stream.avvideo"):
        Player(comp, src, sink, iterations=1, threads=False).run()
    assert src.last_pts >= 11.9 and len(sink.frames) + src.skipped == 360
    assert sum("wall clock" in r.getMessage() for r in caplog.records) == 1


def test_file_rendering_decodes_every_frame_without_sound(tmp_path):
    from rtdefocus.stream.avvideo import AvVideoSource

    path = make_video(tmp_path / "v.mp4", seconds=1.0)
    with AvVideoSource(path) as src:
        frames = list(src)
    assert not src.live and len(frames) == 30 and [f.index for f in frames] == list(range(30))
    assert frames[0].image.mean() > 200 and frames[1].image.mean() < 100


def test_no_sound_device_falls_back_to_the_wall_clock(monkeypatch, caplog):
    import sys

    import rtdefocus.stream.audio as audio

    monkeypatch.setitem(sys.modules, "sounddevice", None)
    monkeypatch.setattr(audio, "_warned", False)
    with caplog.at_level("WARNING", logger="rtdefocus.stream.audio"):
        a, b = open_audio_output(), open_audio_output()
    assert isinstance(a, WallClock) and isinstance(b, WallClock)
    warnings = [r for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 1 and "libportaudio2" in warnings[0].getMessage()
    assert isinstance(open_audio_output(mute=True), WallClock)


def _undecodable(tmp_path):
    """An MP4 whose index (moov, written first) opens but whose frames were cut off."""
    good = tmp_path / "good.mp4"
    with av.open(str(good), "w", options={"movflags": "faststart"}) as c:
        vs = c.add_stream("mpeg4", rate=25)
        vs.width, vs.height, vs.pix_fmt = 32, 24, "yuv420p"
        for i, img in enumerate(synthetic_frames(25, size=(32, 24))):
            vf = av.VideoFrame.from_ndarray(img, format="rgb24")
            vf.pts = i
            for p in vs.encode(vf):
                c.mux(p)
        for p in vs.encode(None):
            c.mux(p)
    data = good.read_bytes()
    mdat = data.index(b"mdat")
    bad = tmp_path / "cut.mp4"
    bad.write_bytes(data[:mdat + 4])
    return bad


@pytest.mark.parametrize("decoder", ["pyav", "opencv"])
def test_video_that_opens_but_does_not_decode_is_an_error(tmp_path, decoder):
    from rtdefocus.stream import VideoSource
    from rtdefocus.stream.avvideo import AvVideoSource

    bad = _undecodable(tmp_path)
    opener = AvVideoSource if decoder == "pyav" else VideoSource
    with pytest.raises(InputError, match="no frame could be decoded.*re-encode"):
        with opener(bad) as src:
            src.read()


def test_cli_undecodable_video_exits_1_with_one_line(tmp_path, calib, capsys):
    setup = calib.save(tmp_path / "setup.npz")
    bad = _undecodable(tmp_path)
    assert cli.main(["play", str(setup), str(bad), "--out", str(tmp_path / "out")]) == 1
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert len(err.splitlines()) == 1 and "ffmpeg" in err and "frames out" not in cap.out


# --------------------------------------------------------------------------- playlists
def _mixed_folder(tmp_path):
    folder = tmp_path / "show"
    folder.mkdir()
    write_image(folder / "01 title.png", synthetic_frames(1, seed=1)[0])
    make_pdf(folder / "02 talk.pdf", colours=PAGE_COLOURS[:2])
    make_video(folder / "03 clip.mp4", seconds=0.2, size=PROJ)
    write_image(folder / "10 thanks.png", synthetic_frames(1, seed=2)[0])
    (folder / "notes.txt").write_text("not shown")
    return folder


def test_playlist_groups_stills_and_plays_in_name_order(tmp_path):
    folder = _mixed_folder(tmp_path)
    items = playlist(folder)
    assert [[p.name for p in i] if isinstance(i, list) else i.rsplit("/", 1)[1] for i in items] == [
        ["01 title.png", "02 talk.pdf"], "03 clip.mp4", ["10 thanks.png"]]
    with pytest.raises(InputError, match="playlist"):
        open_source(folder)
    assert playlist(tmp_path / "x.png") == [str(tmp_path / "x.png")]


def test_cli_playlist_to_files_writes_every_item_in_order(tmp_path, calib):
    folder = _mixed_folder(tmp_path)
    setup = calib.save(tmp_path / "setup.npz")
    assert cli.main(["-q", "play", str(setup), str(folder), "--out", str(tmp_path / "out"),
                     "--iterations", "2", "--no-cache"]) == 0
    outs = sorted((tmp_path / "out").glob("frame_*.png"))
    # 1 image + 2 pages + 6 video frames + 1 image, numbered on across the items
    assert [p.name for p in outs] == [f"frame_{i:06d}.png" for i in range(10)]
    c = rd.Compensator(calib)
    last = c.compensate(read_image(folder / "10 thanks.png"), iterations=2, warm_start=False)
    assert max_abs(read_image(outs[-1]), last) <= 1
    with SlidesSource(folder / "02 talk.pdf", size=PROJ) as deck:
        page2 = c.compensate(deck.load(1), iterations=2, warm_start=False)
    assert max_abs(read_image(outs[2]), page2) <= 1
    assert cli.main(["-q", "play", str(setup), str(folder), "--out", "null", "--loop"]) == 1


def _keyed_show(tmp_path, comp, keys, **options):
    folder = tmp_path / "show"
    folder.mkdir(parents=True)
    write_image(folder / "a.png", synthetic_frames(1, seed=1)[0])
    write_image(folder / "b.png", synthetic_frames(1, seed=2)[0])
    make_video(folder / "c.mp4", seconds=0.2, size=PROJ)
    sink = RecordingSink(realtime=True, keys=keys)
    show = Show(comp, folder, sink, audio=False, iterations=1, **options)
    return show, sink, show.run()


def test_window_show_moves_on_from_the_deck_and_ends_black_until_a_key(tmp_path, comp):
    # right, right: through the deck and on to the video; "x" (no action) for each video frame
    # and for the black end, which waits for any key
    show, sink, stats = _keyed_show(tmp_path, comp, ["right", "right"] + ["x"] * 20)
    assert len(stats) == 2 and not show.quit
    assert sink.indices[:2] == [0, 1] and stats[1].frames_out >= 2
    assert not sink.frames[-1].any(), "the show ends on a black projector"
    assert sink.frames[-2].any()
    show, sink, _ = _keyed_show(tmp_path / "b", comp, ["right", "right"] + ["x"] * 20,
                                exit_at_end=True)
    assert sink.frames[-1].any(), "--exit-at-end leaves without the black frame"


def test_window_show_loops_until_quit(tmp_path, comp):
    keys = ["right", "right"] + ["x"] * 5 + ["right", "q"]
    show, sink, stats = _keyed_show(tmp_path, comp, keys, loop=True)
    assert show.quit and len(stats) >= 3
    first = sink.frames[0]
    again = [i for i, f in enumerate(sink.frames[1:], 1) if np.array_equal(f, first)]
    assert again, "the deck came round again"
    assert all(f.any() for f in sink.frames), "no black end while looping"


# --------------------------------------------------------------------------- placement
def _marked(w, h):
    img = np.full((h, w, 3), 128, np.uint8)
    img[h // 2 - 1:h // 2 + 1, w // 2 - 1:w // 2 + 1] = (255, 0, 0)   # the centre
    img[0, 0] = img[-1, -1] = (0, 255, 0)                               # two corners
    return img


def test_fit_contain_and_cover_and_margins():
    wide = _marked(100, 40)
    c = Placement((64, 48), "contain")(wide)
    rows = np.flatnonzero(c.any(axis=(1, 2)))
    assert c.shape == (48, 64, 3) and c[:, 0].any() and (rows[0], rows[-1]) == (11, 36)
    cov = Placement((64, 48), "cover")(wide)
    assert cov.any(axis=2).all(), "cover fills the frame"
    red = cov[..., 0].astype(int) - cov[..., 1]
    assert np.unravel_index(red.argmax(), red.shape) in {(23, 31), (23, 32), (24, 31), (24, 32)}
    assert not ((cov[..., 1] > 160) & (cov[..., 0] < 100)).any(), "the sides are cropped"
    m = Placement((64, 48), "cover", 0.1)(wide)
    cols, rows = np.flatnonzero(m.any(axis=(0, 2))), np.flatnonzero(m.any(axis=(1, 2)))
    assert (cols[0], cols[-1], rows[0], rows[-1]) == (6, 57, 5, 42)
    px = Placement((64, 48), "contain", 8)(_marked(64, 48))
    cols, rows = np.flatnonzero(px.any(axis=(0, 2))), np.flatnonzero(px.any(axis=(1, 2)))
    assert (cols[0], cols[-1], rows[0], rows[-1]) == (10, 52, 8, 39)   # 43x32 in the 48x32 box
    with pytest.raises(InputError, match="margin"):
        Placement((64, 48), "contain", 24)
    with pytest.raises(InputError, match="fit"):
        Placement((64, 48), "stretch")


def test_cli_fit_and_margin_reach_the_compensator(tmp_path, calib):
    setup = calib.save(tmp_path / "setup.npz")
    img = synthetic_frames(1, size=(90, 40), seed=3)[0]
    write_image(tmp_path / "wide.png", img)
    c = rd.Compensator(calib)
    for fit, margin in (("cover", None), ("contain", "4px")):
        out = tmp_path / f"{fit}.png"
        args = ["-q", "play", str(setup), str(tmp_path / "wide.png"), "--out", str(out),
                "--iterations", "2", "--no-cache", "--fit", fit]
        assert cli.main(args + (["--margin", margin] if margin else [])) == 0
        placed = Placement(PROJ, fit, 4 if margin else 0.0)(img)
        assert max_abs(read_image(out), c.compensate(placed, iterations=2, warm_start=False)) <= 1
    assert cli.main(["-q", "play", str(setup), str(tmp_path / "wide.png"), "--out", "null",
                     "--margin", "0.7"]) == 1


def test_placement_applies_to_a_video_source(tmp_path):
    path = make_video(tmp_path / "v.mp4", seconds=0.2, size=(32, 24))
    place = Placement(PROJ, "contain", 0.25)
    with open_source(path, placement=place) as src:
        frames = list(src)
    assert len(frames) == 6 and all(f.image.shape == (PROJ[1], PROJ[0], 3) for f in frames)
    assert not frames[0].image[:12].any() and frames[0].image[12:36, 16:48].mean() > 200


def test_null_sink_of_a_playlist_counts_every_item(tmp_path, comp):
    folder = _mixed_folder(tmp_path)
    with NullSink() as sink:
        stats = Show(comp, folder, sink, iterations=1).run()
    assert [s.frames_out for s in stats] == [3, 6, 1] and sink.count == 10
    with ImageSequenceSink(tmp_path / "o") as sink:
        Show(comp, [[folder / "01 title.png"]], sink, iterations=1).run()
    assert len(list((tmp_path / "o").glob("*.png"))) == 1


def test_cli_video_file_out_keeps_the_source_rate(tmp_path, calib):
    import cv2

    setup = calib.save(tmp_path / "setup.npz")
    clip = make_video(tmp_path / "clip.mp4", seconds=0.4, fps=25, size=PROJ)
    assert cli.main(["-q", "play", str(setup), str(clip), "--out", str(tmp_path / "o.mp4"),
                     "--iterations", "1"]) == 0
    cap = cv2.VideoCapture(str(tmp_path / "o.mp4"))
    assert cap.get(cv2.CAP_PROP_FPS) == 25 and int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 10
    cap.release()


def test_sound_device_output_counts_what_the_callback_played(monkeypatch):
    """SoundDeviceOutput against a stand-in for the sounddevice module (no PortAudio here): the
    callback plays the queued samples in order, its position is what was played less the
    output latency, an underrun does not move it, and after end() silence keeps it going."""
    import sys
    import types

    from rtdefocus.stream.audio import SoundDeviceOutput

    class Stream:
        latency, active = 0.02, False

        def __init__(self, **kw):
            self.kw = kw

        def start(self):
            self.active = True

        def stop(self):
            self.active = False

        def close(self):
            self.active = False

    fake = types.SimpleNamespace(
        query_devices=lambda device, kind: {"max_output_channels": 2, "default_samplerate": 1000.0},
        OutputStream=Stream)
    monkeypatch.setitem(sys.modules, "sounddevice", fake)
    out = SoundDeviceOutput(channels=2)
    assert out.rate == 1000 and out.channels == 2 and out._stream.active
    ramp = np.arange(200, dtype=np.float32).reshape(100, 2) / 200
    out.write(ramp[:60])
    out.write(ramp[60:])
    buf = np.full((80, 2), 9.0, np.float32)
    out._callback(buf, 80, None, None)
    assert np.array_equal(buf, ramp[:80]) and out.position() == pytest.approx(0.08 - 0.02)
    out._callback(buf, 80, None, None)                  # 20 left: the rest is an underrun
    assert np.array_equal(buf[:20], ramp[80:]) and not buf[20:].any()
    assert out.position() == pytest.approx(0.10 - 0.02)
    out._callback(buf, 80, None, None)
    assert out.position() == pytest.approx(0.10 - 0.02), "an underrun does not move the clock"
    out.end()
    out._callback(buf, 50, None, None)
    at_end = out.position()
    assert at_end == pytest.approx(0.10 - 0.02, abs=0.01)
    time.sleep(0.05)
    out._callback(buf, 50, None, None)
    assert out.position() - at_end >= 0.04, "after the end the clock runs on at wall time"
    out.set_paused(True)
    assert not out._stream.active
    out.close()


def test_without_pyav_the_window_plays_videos_through_opencv(tmp_path, monkeypatch, caplog):
    import sys

    import rtdefocus.stream.sources as sources
    from rtdefocus.stream import VideoSource
    from rtdefocus.stream.avvideo import AvVideoSource

    clip = make_video(tmp_path / "clip.mp4", seconds=0.2)
    with open_source(clip, realtime=True, audio=False) as src:
        assert isinstance(src, AvVideoSource) and src.live
    monkeypatch.setitem(sys.modules, "av", None)
    monkeypatch.setattr(sources, "_told_no_pyav", False)
    with caplog.at_level("WARNING", logger="rtdefocus.stream.sources"):
        with open_source(clip, realtime=True) as src:
            frames = list(src)
    assert isinstance(src, VideoSource) and not src.live and len(frames) == 6
    assert any("rtdefocus[show]" in r.getMessage() for r in caplog.records)
