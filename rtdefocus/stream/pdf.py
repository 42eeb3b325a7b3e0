"""PDF decks: each page rendered (pypdfium2, the PDFium engine browsers use) as one slide.

Pages are rendered at the size they will be shown at (the projector's, aspect kept), so text
stays as sharp as the projector can show it; the player then treats them exactly as image
slides (refined until converged, cached on disk by content).

pypdfium2 is a dependency of the package; a broken install says how to mend it.
"""

from __future__ import annotations

import logging
import threading
from pathlib import Path

import numpy as np

from ..errors import InputError

log = logging.getLogger(__name__)

#: Render size when none is given (a 1080p projector).
DEFAULT_SIZE = (1920, 1080)

# PDFium is not thread-safe: one lock for every document of the process.
_LOCK = threading.Lock()


def _pdfium():
    try:
        import pypdfium2
    except ImportError:
        raise InputError("showing a PDF needs pypdfium2: pip install pypdfium2 (or export "
                         "the slides as PNG images into a folder)") from None
    return pypdfium2


class PdfDeck:
    """The pages of one PDF file, rendered on demand.

    Parameters
    ----------
    path : the PDF file.
    size : (width, height) each page is fitted into (aspect kept), default 1920x1080.

    Raises
    ------
    InputError
        The file does not open as a PDF (damaged, password-protected, not a PDF) or has no page.
    """

    def __init__(self, path: str | Path, size: tuple[int, int] | None = None):
        pdfium = _pdfium()
        self.path = Path(path)
        self.size = tuple(int(v) for v in (size or DEFAULT_SIZE))
        try:
            with _LOCK:
                self._doc = pdfium.PdfDocument(str(self.path))
                self.n_pages = len(self._doc)
        except pdfium.PdfiumError as exc:
            raise InputError(f"cannot open {str(self.path)!r} as a PDF ({exc}): it is damaged, "
                             "password-protected or not a PDF; export it again from the "
                             "presentation program (File > Export > PDF) or export the slides as "
                             "PNG images into a folder") from None
        if self.n_pages == 0:
            raise InputError(f"{str(self.path)!r} has no pages; export the deck again")

    def render(self, page: int) -> np.ndarray:
        """Page ``page`` (from 0) as RGB uint8 ``(H, W, 3)``, fitted into :attr:`size`."""
        if not 0 <= page < self.n_pages:
            raise InputError(f"page {page} out of range 0..{self.n_pages - 1} of {self.path.name}")
        w, h = self.size
        with _LOCK:
            pg = self._doc[page]
            try:
                pw, ph = pg.get_size()                 # points
                scale = min(w / pw, h / ph)
                bitmap = pg.render(scale=scale, rev_byteorder=True, fill_color=(255, 255, 255, 255))
                rgb = np.array(bitmap.to_numpy()[..., :3], np.uint8)   # a copy: the bitmap is freed
            finally:
                pg.close()
        log.debug("rendered %s page %d at %dx%d", self.path.name, page + 1, rgb.shape[1], rgb.shape[0])
        return rgb

    def close(self) -> None:
        if self._doc is not None:
            with _LOCK:
                self._doc.close()
            self._doc = None
