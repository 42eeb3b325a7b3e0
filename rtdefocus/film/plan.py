"""Chunks of a film and the work folder that keeps the finished ones (pure Python, no devices).

A chunk is frames ``start`` … ``stop - 1``; its solve starts ``overlap`` frames earlier, at
``lead``, from the cold start, and those lead frames are compensated and thrown away: by
``start`` the warm start carries as much as it would in one serial pass (the seam does not
show).

The work folder holds one sub-folder per render key (a hash of the set-up file, the film file
and every option that changes a pixel), with the chunk files and ``manifest.json``. Chunks are
written to a temporary name and renamed when complete, the manifest likewise, so a render
killed at any moment leaves only complete chunks behind, and a second run with the same key
takes them as done.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError

__all__ = ["Chunk", "plan_chunks", "file_digest", "render_key", "WorkFolder"]

MANIFEST = "manifest.json"


@dataclass(frozen=True)
class Chunk:
    """Frames ``start`` … ``stop - 1``, solved from frame ``lead`` (``lead <= start``)."""

    index: int
    start: int
    stop: int
    lead: int

    @property
    def frames(self) -> int:
        return self.stop - self.start

    @property
    def name(self) -> str:
        return f"chunk_{self.index:05d}.nut"


def plan_chunks(n_frames: int, chunk_frames: int, overlap: int) -> list[Chunk]:
    """Cut ``n_frames`` into chunks of ``chunk_frames`` (the last one may be shorter), each
    solved from ``overlap`` frames before its start (none before frame 0)."""
    if n_frames < 1:
        raise InputError(f"the film has no frames to render (found {n_frames})")
    if chunk_frames < 1 or overlap < 0:
        raise InputError(f"chunk_frames must be >= 1 and overlap >= 0; got {chunk_frames}, "
                         f"{overlap}")
    return [Chunk(k, s, min(s + chunk_frames, n_frames), max(0, s - overlap))
            for k, s in enumerate(range(0, n_frames, chunk_frames))]


def file_digest(path: str | Path) -> str:
    """BLAKE2b of a file's bytes (hex, 32 characters)."""
    h = hashlib.blake2b(digest_size=16)
    with open(path, "rb") as f:
        while block := f.read(1 << 22):
            h.update(block)
    return h.hexdigest()


def render_key(settings: dict) -> str:
    """The work sub-folder's name: a hash of the settings (JSON, keys sorted)."""
    text = json.dumps(settings, sort_keys=True, default=str)
    return hashlib.blake2b(text.encode(), digest_size=8).hexdigest()


class WorkFolder:
    """``root/<key>/``: the finished chunk files and ``manifest.json`` of one render.

    The manifest records ``settings`` and, per finished chunk, its file, frames and size; only
    the process that schedules the render writes it.
    """

    def __init__(self, root: str | Path, settings: dict):
        self.key = render_key(settings)
        self.path = Path(root) / self.key
        try:
            self.path.mkdir(parents=True, exist_ok=True)
            probe = self.path / f".write-test-{os.getpid()}"
            probe.write_bytes(b"")
            probe.unlink()
        except OSError as exc:
            raise InputError(f"cannot write the work folder {str(self.path)!r} ({exc.strerror}); "
                             "pass a writable one with --work DIR") from None
        self.settings = settings
        self.manifest = self._load()

    def _load(self) -> dict:
        try:
            data = json.loads((self.path / MANIFEST).read_text())
            if data.get("key") == self.key:
                return data
        except (OSError, ValueError):
            pass
        return {"key": self.key, "settings": self.settings, "chunks": {}}

    def chunk_path(self, chunk: Chunk) -> Path:
        return self.path / chunk.name

    def done(self, chunks: list[Chunk]) -> set[int]:
        """Indices of the chunks already finished: in the manifest with a file of the recorded
        size, or a complete chunk file the manifest missed (the render was killed between a
        worker's rename and the manifest's update); the manifest is brought up to date."""
        # a stopped render's unfinished chunks (temporary names) are rendered again
        for tmp in self.path.glob(".chunk_*.tmp"):
            tmp.unlink(missing_ok=True)
        out = set()
        recorded = self.manifest["chunks"]
        changed = False
        for c in chunks:
            p = self.chunk_path(c)
            if not p.is_file():
                if str(c.index) in recorded:
                    del recorded[str(c.index)]
                    changed = True
                continue
            entry = recorded.get(str(c.index))
            if entry is not None and entry.get("size") != p.stat().st_size:
                continue
            if entry is None:
                recorded[str(c.index)] = {"file": c.name, "start": c.start, "stop": c.stop,
                                          "size": p.stat().st_size}
                changed = True
            out.add(c.index)
        if changed:
            self._save()
        return out

    def record(self, chunk: Chunk, info: dict | None = None) -> None:
        """Mark ``chunk`` finished (its file is in place)."""
        entry = {"file": chunk.name, "start": chunk.start, "stop": chunk.stop,
                 "size": self.chunk_path(chunk).stat().st_size}
        if info:
            entry.update(info)
        self.manifest["chunks"][str(chunk.index)] = entry
        self._save()

    def _save(self) -> None:
        tmp = self.path / f".{MANIFEST}.{os.getpid()}.tmp"
        tmp.write_text(json.dumps(self.manifest, indent=1, sort_keys=True, default=str))
        os.replace(tmp, self.path / MANIFEST)
