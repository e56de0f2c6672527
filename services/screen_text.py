"""Text on a screenshot, read by OCR: the words a PNG shows and where they are.

Calls the Tesseract OCR engine's command line (``tesseract - - --psm 11 tsv``: the image
on standard input, "sparse text" page segmentation, which finds scattered labels rather
than paragraphs, and its TSV output: one row per word with its pixel box and confidence;
https://tesseract-ocr.github.io/tessdoc/Command-Line-Usage.html). Debian ships it as
``tesseract-ocr`` (5.3.0 with the ``eng`` model on Debian 12); ``SSMPC_TESSERACT`` names
another executable. It runs with ``OMP_THREAD_LIMIT=1``: on 2 busy cores its OpenMP
threads spun (a 2560 x 1600 screenshot took 7.8 s wall, 5.7 s of it system time, against
1.1-2.2 s on one thread).

Light text on a dark background (the Rerun viewer's default theme) is inverted to dark
on light first (:attr:`OcrSettings.invert`), and small text is enlarged
(:attr:`OcrSettings.upscale`, Lanczos). :func:`find_phrase` then looks for a phrase as
whole words on one line, with the letters OCR confuses folded together (``1 l I |``,
``0 o O``; case; ``. , : ; '`` dropped), so "log10 J (eq. 4.6)" read as "1og10 J (eq
4.6)" is found, and "active models" is not "active model".

Measured: the 11 panel titles of the TE trend display (6 key CVs, "MVs, % of range",
"active model", "log10 J (eq. 4.6)", "events", "timing (ms)"; rerun-sdk 0.41 web viewer,
dark theme, headless Chromium 150, viewport 1280 x 800 CSS px), 5 renders of one
recording per row (they differ in under 0.2 % of their pixels), titles found by
:func:`find_phrase` over the whole screenshot (tesseract 5.3.0, ``--psm 11``, one
thread, at load 7-10 on 2 cores):

=================================  =================  ==============================  =========
device scale, preparation          titles found       missed (renders of 5)           reading
=================================  =================  ==============================  =========
1, grey                            7-8 of 11          MVs, active model, log10 J (5)  2.5-3.1 s
                                                      events (4)
1, grey inverted                   7-8 of 11          the same                        1.7-2.0 s
1, grey inverted, enlarged x2      11 of 11 (5 of 5)  -                               1.9-2.8 s
2, grey                            11 of 11 (5 of 5)  -                               3.5-5.4 s
2, grey inverted                   11 of 11 (5 of 5)  -                               3.3-3.7 s
=================================  =================  ==============================  =========

Read exactly (a substring of a line, no folding), "log10 J (eq. 4.6)" was missed in all
5 renders of each of the last three rows ("1og10", "10g10", "(eq"); the other titles were
read letter for letter. Device scale 2 costs the browser 4 times the pixels: the viewer
drew the recording in 111-132 s against 32-39 s at scale 1 (3 renders each, taken in
turn; software WebGL, load 7-11), so scale 1 enlarged x2 is the cheaper way to the same
reading. Its settings read all 11 titles, each in its own title bar
(:func:`services.telemetry_view.check_titles`), in 12 renders of 5 recordings at 1280 x
800 and in one at 1600 x 1000.
"""

from __future__ import annotations

import io
import os
import re
import shutil
import subprocess
from dataclasses import dataclass

import numpy as np

__all__ = ["OcrUnavailable", "OcrSettings", "Word", "TextLine", "find_tesseract",
           "read_lines", "parse_tsv", "find_phrase", "fold"]


class OcrUnavailable(RuntimeError):
    """No tesseract executable to run (the reason and the remedy are the message)."""


def find_tesseract() -> str | None:
    """The tesseract executable: ``SSMPC_TESSERACT`` if set, else ``tesseract`` on
    ``PATH``; None when there is none."""
    env = os.environ.get("SSMPC_TESSERACT")
    if env:
        return shutil.which(env)
    return shutil.which("tesseract")


@dataclass(frozen=True)
class OcrSettings:
    """How a screenshot is prepared and read.

    Parameters
    ----------
    invert : bool
        Invert the grey levels first (light text on dark becomes dark on light).
    upscale : int
        Enlarge the image this many times (1-4) before reading; boxes are given back in
        the input's pixels.
    psm : int
        Tesseract's page segmentation mode (0-13; 11: sparse text, 6: one block,
        7: one line).
    lang : str
        Tesseract language model(s), e.g. ``"eng"`` or ``"eng+deu"``.
    timeout_s : float
        Longest wait for one reading, s.
    """

    invert: bool = True
    upscale: int = 1
    psm: int = 11
    lang: str = "eng"
    timeout_s: float = 60.0

    def __post_init__(self) -> None:
        if not isinstance(self.upscale, int) or not 1 <= self.upscale <= 4:
            raise ValueError(f"upscale: {self.upscale!r} is not an integer in 1..4")
        if not isinstance(self.psm, int) or not 0 <= self.psm <= 13:
            raise ValueError(f"psm: {self.psm!r} is not a page segmentation mode 0..13")
        if not re.fullmatch(r"[A-Za-z_]+(\+[A-Za-z_]+)*", self.lang):
            raise ValueError(f"lang: {self.lang!r} is not a tesseract language like 'eng'")
        if not self.timeout_s > 0:
            raise ValueError("timeout_s must be > 0 s")


@dataclass(frozen=True)
class Word:
    """One word read: its text, its box in px (``left``, ``top``, ``width``,
    ``height``, of the image given) and tesseract's confidence, 0-100."""

    text: str
    left: int
    top: int
    width: int
    height: int
    conf: float


@dataclass(frozen=True)
class TextLine:
    """The words tesseract put on one line, left to right."""

    words: tuple[Word, ...]

    @property
    def text(self) -> str:
        return " ".join(w.text for w in self.words)

    @property
    def box(self) -> tuple[int, int, int, int]:
        """``(x0, y0, x1, y1)`` px around all its words."""
        return _box(self.words)


def _box(words) -> tuple[int, int, int, int]:
    return (min(w.left for w in words), min(w.top for w in words),
            max(w.left + w.width for w in words), max(w.top + w.height for w in words))


def parse_tsv(tsv: str, scale: float = 1.0) -> list[TextLine]:
    """Lines of words from tesseract's TSV output (header row, then ``level page_num
    block_num par_num line_num word_num left top width height conf text``; words are
    level 5), in reading order; boxes divided by ``scale`` (the upscale applied)."""
    lines: dict[tuple[str, ...], list[Word]] = {}
    for row in tsv.splitlines()[1:]:
        f = row.split("\t")
        if len(f) != 12 or f[0] != "5" or not f[11].strip():
            continue
        left, top, width, height = (int(v) for v in f[6:10])
        word = Word(f[11].strip(), round(left / scale), round(top / scale),
                    round(width / scale), round(height / scale), float(f[10]))
        lines.setdefault(tuple(f[1:5]), []).append(word)
    return [TextLine(tuple(ws)) for ws in lines.values()]


def _prepare(png: bytes, s: OcrSettings) -> bytes:
    """The image tesseract reads: grey levels (the brightest channel, so coloured text
    stays legible), inverted and enlarged as set; PNG bytes."""
    from PIL import Image

    with Image.open(io.BytesIO(png)) as im:
        rgb = np.asarray(im.convert("RGB"))
    grey = rgb.max(axis=2)
    if s.invert:
        grey = 255 - grey
    out = Image.fromarray(grey.astype(np.uint8))
    if s.upscale > 1:
        out = out.resize((out.width * s.upscale, out.height * s.upscale), Image.LANCZOS)
    buf = io.BytesIO()
    out.save(buf, "PNG")
    return buf.getvalue()


def read_lines(png: bytes, settings: OcrSettings | None = None,
               executable: str | None = None) -> list[TextLine]:
    """The lines of text a PNG shows, each with its words and their boxes.

    Parameters
    ----------
    png : bytes
        A PNG image (a screenshot).
    settings : OcrSettings, optional
    executable : str, optional
        Default :func:`find_tesseract`.

    Returns
    -------
    list of TextLine
        Boxes in the PNG's pixels.

    Raises
    ------
    OcrUnavailable
        No tesseract executable.
    ValueError
        ``png`` is not an image.
    RuntimeError
        Tesseract failed (its message is in this one's).
    TimeoutError
        No result within ``timeout_s``.
    """
    s = settings or OcrSettings()
    exe = executable or find_tesseract()
    if exe is None:
        raise OcrUnavailable("no tesseract on PATH (Debian: apt-get install tesseract-ocr; "
                             "or set SSMPC_TESSERACT)")
    try:
        image = _prepare(png, s)
    except OSError as exc:  # PIL.UnidentifiedImageError is an OSError
        raise ValueError(f"not an image: {exc}") from exc
    env = dict(os.environ, OMP_THREAD_LIMIT="1")
    try:
        done = subprocess.run([exe, "-", "-", "--psm", str(s.psm), "-l", s.lang, "tsv"],
                              input=image, capture_output=True, timeout=s.timeout_s, env=env)
    except subprocess.TimeoutExpired as exc:
        raise TimeoutError(f"tesseract: no result in {s.timeout_s:g} s") from exc
    except OSError as exc:
        raise OcrUnavailable(f"{exe}: {exc}") from exc
    if done.returncode != 0:
        raise RuntimeError(f"tesseract exited with {done.returncode}: "
                           f"{done.stderr.decode(errors='replace')[-600:]}")
    return parse_tsv(done.stdout.decode(errors="replace"), scale=s.upscale)


_FOLD = str.maketrans({"1": "l", "I": "l", "|": "l", "0": "o", "O": "o"})
_DROPPED = re.compile(r"[.,:;'`]")


def fold(text: str) -> str:
    """``text`` with the letters OCR confuses made one (``1 I |`` -> ``l``, ``0 O`` ->
    ``o``), lower case, ``. , : ; '`` and backquotes dropped."""
    return _DROPPED.sub("", text.translate(_FOLD).casefold())


def find_phrase(lines: list[TextLine], phrase: str) -> list[tuple[int, int, int, int]]:
    """Where ``phrase`` is read: the box ``(x0, y0, x1, y1)`` px of each occurrence, in
    the order of ``lines``.

    An occurrence is the phrase's words, compared after :func:`fold`, on one line and
    bounded there by a non-alphanumeric character or the line's end on either side (so
    a title that OCR runs into the icon before it, "(active model", counts, and "active
    models" does not). An empty phrase is never found.
    """
    want = " ".join(fold(phrase).split())
    if not want:
        return []
    found = []
    for line in lines:
        spans, parts, pos = [], [], 0
        for w in line.words:
            t = fold(w.text)
            if not t:
                continue
            if parts:
                pos += 1
            spans.append((pos, pos + len(t), w))
            parts.append(t)
            pos += len(t)
        text = " ".join(parts)
        for m in re.finditer(re.escape(want), text):
            a, b = m.start(), m.end()
            if (a > 0 and text[a - 1].isalnum()) or (b < len(text) and text[b].isalnum()):
                continue
            found.append(_box([w for s0, s1, w in spans if s0 < b and s1 > a]))
    return found
