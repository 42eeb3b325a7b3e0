"""Wall textures of the virtual set-up: albedo patterns fixed to the walls, in metres along
them, so that they stay put when the projector or the camera moves."""

from __future__ import annotations

import math

import numpy as np

TEXTURES = ("none", "faint", "fabric")
FAR_ALBEDO = 0.6            # albedo of a far wall seen through a gap (a grey one)


def fabric_factor(s: np.ndarray, y: np.ndarray, wall: np.ndarray) -> np.ndarray:
    """The "fabric" texture's albedo factor (3, N) at wall coordinates ``s`` (m along the wall
    from the fold), ``y`` (m, down; 0 at the projector's centre row) on ``wall`` (0 left, 1 right)."""
    out = np.ones((3, s.size))
    w0, w1 = wall == 0, wall == 1
    # Left: a woven partition, ±8 % in a 3 cm basket weave.
    weave = 1.0 + 0.08 * np.sin(2 * math.pi * s / 0.03) * np.sin(2 * math.pi * y / 0.03)
    out[:, w0] *= weave[w0]
    # Right: soft wood-grain-like bands (±6 %, 9 cm, slightly wavy) ...
    grain = 1.0 + 0.06 * np.sin(2 * math.pi * (y + 0.02 * np.sin(2 * math.pi * s / 0.4)) / 0.09)
    out[:, w1] *= grain[w1]
    # ... and a printed poster, coloured diagonal stripes (albedo × 0.45..1.0 per channel).
    poster = w1 & (s > 0.30) & (s < 0.80) & (y > -0.40) & (y < 0.10)
    ph = 2 * math.pi * (s / 0.16 + y / 0.23)
    for c, off in enumerate((0.0, 2.1, 4.2)):
        out[c, poster] *= 0.725 + 0.275 * np.cos(ph[poster] + off)
    return out



def wall_albedo(base_albedo, walls, pts_w: np.ndarray, wall: np.ndarray, *, amplitude: float,
                texture: str, phase: np.ndarray) -> np.ndarray:
    """RGB albedo (3, N) of world points ``pts_w`` (3, N) on ``wall`` (index into ``walls``,
    -1 = none: albedo 0): each wall's ``base_albedo`` (walls past its rows, a far wall seen
    through a gap: :data:`FAR_ALBEDO`) times a faint smooth pattern of relative
    ``amplitude`` (phases ``phase``), and the "fabric" ``texture``'s weave, grain and poster."""
    base = np.asarray(base_albedo, dtype=np.float64)
    if len(walls) > len(base):
        base = np.vstack([base, np.full((len(walls) - len(base), 3), FAR_ALBEDO)])
    out = np.zeros((3, wall.size))
    hit = wall >= 0
    out[:, hit] = base[wall[hit]].T
    if amplitude > 0 and hit.any():
        s, y = np.zeros(wall.size), pts_w[1].copy()
        for i, w in enumerate(walls):
            sel = wall == i
            if w.tex is not None:       # a room's wall or ceiling: its own two axes
                s[sel], y[sel] = w.tex @ (pts_w[:, sel] - w.origin[:, None])
                continue
            e = w.e if w.e is not None else np.cross([0.0, 1.0, 0.0], w.n)
            s[sel] = e @ (pts_w[:, sel] - w.origin[:, None])
        ph = phase
        # Faint (±texture) smooth pattern fixed to the wall, in metres along it.
        tex = 1.0 + 0.5 * amplitude * (np.sin(2 * math.pi * s / 0.37 + ph[0, 0])
                                       * np.sin(2 * math.pi * y / 0.29 + ph[0, 1])
                                       + np.sin(2 * math.pi * (s + y) / 0.61 + ph[0, 2]))
        out[:, hit] *= tex[hit]
        if texture == "fabric":
            out[:, hit] *= fabric_factor(s[hit], y[hit], wall[hit])
    return out
