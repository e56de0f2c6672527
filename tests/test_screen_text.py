"""Text read off a screenshot (services.screen_text): tesseract's TSV becomes lines of
words with boxes, a phrase is found as whole words despite the letters OCR confuses,
and a real reading of drawn text finds it where it was drawn. Settings and inputs that
cannot work are clear errors."""

import io

import pytest
from system_tools import require

from services.screen_text import (
    OcrSettings,
    OcrUnavailable,
    TextLine,
    Word,
    find_phrase,
    find_tesseract,
    fold,
    parse_tsv,
    read_lines,
)

HEADER = ("level\tpage_num\tblock_num\tpar_num\tline_num\tword_num\tleft\ttop\twidth\theight"
          "\tconf\ttext")


def _line(*words, top=10):
    """A line of words 10 px apart, each 8 px per letter wide, 12 px high."""
    out, x = [], 20
    for t in words:
        out.append(Word(t, x, top, 8 * len(t), 12, 90.0))
        x += 8 * len(t) + 10
    return TextLine(tuple(out))


def test_tsv_rows_become_lines_of_words_with_boxes_in_input_pixels():
    tsv = "\n".join([
        HEADER,
        "1\t1\t0\t0\t0\t0\t0\t0\t2560\t1600\t-1\t",
        "4\t1\t1\t1\t1\t0\t40\t20\t300\t30\t-1\t",
        "5\t1\t1\t1\t1\t1\t40\t20\t100\t30\t96.5\tactive",
        "5\t1\t1\t1\t1\t2\t160\t22\t180\t28\t91.0\tmodel",
        "5\t1\t1\t1\t1\t3\t400\t20\t10\t30\t0.0\t ",  # an empty word is left out
        "5\t1\t2\t1\t1\t1\t1000\t600\t120\t30\t88.0\tevents",
    ])
    lines = parse_tsv(tsv, scale=2)
    assert [ln.text for ln in lines] == ["active model", "events"]
    first = lines[0].words[0]
    assert (first.left, first.top, first.width, first.height, first.conf) == (20, 10, 50, 15,
                                                                                96.5)
    assert lines[0].box == (20, 10, 170, 25)  # 40/2 .. (160 + 180)/2, 20/2 .. 50/2
    assert parse_tsv(HEADER) == []


def test_confusable_letters_fold_together():
    assert fold("1og10 J (eq 4.6)") == fold("log10 J (eq. 4.6)") == "loglo j (eq 46)"
    assert fold("MVs, % of range") == "mvs % of range"


@pytest.mark.parametrize("read, phrase", [
    (("1og10", "J", "(eq", "4.6)"), "log10 J (eq. 4.6)"),  # l read as 1, a dot lost
    (("(active", "model"), "active model"),  # the icon before the title read into it
    (("\\)", "timing", "(ms)"), "timing (ms)"),
    (("MVs,", "%", "of", "range"), "MVs, % of range"),
])
def test_a_phrase_is_found_as_read_by_ocr(read, phrase):
    assert len(find_phrase([_line(*read)], phrase)) == 1


@pytest.mark.parametrize("read, phrase", [
    (("active", "models"), "active model"),  # a renamed panel is not the old one
    (("inactive", "model"), "active model"),
    (("log10", "J"), "log10 J (eq. 4.6)"),  # part of the title only
    (("timing",), "timing (ms)"),
    (("events",), ""),
])
def test_a_phrase_is_not_found_in_other_words(read, phrase):
    assert find_phrase([_line(*read)], phrase) == []


def test_the_box_is_that_of_the_matched_words_only():
    # "XMEAS 8 reactor level (%)" inside a legend entry "@ XMEAS 8 reactor level (%) i"
    line = _line("@", "XMEAS", "8", "reactor", "level", "(%)", "i", top=50)
    (box,) = find_phrase([_line("other", "text"), line], "XMEAS 8 reactor level (%)")
    # "@" from x 20 (8 px wide), "XMEAS" from 38 (40), "8" 88, "reactor" 106 (56),
    # "level" 172 (40), "(%)" 222 (24) to 246; "i" from 256 left out
    assert box == (38, 50, 246, 62)


@pytest.mark.parametrize("kw", [{"upscale": 0}, {"upscale": 1.5}, {"psm": 14},
                                {"lang": "eng; rm -rf"}, {"timeout_s": 0}])
def test_settings_refuse_bad_values(kw):
    with pytest.raises(ValueError):
        OcrSettings(**kw)


def test_missing_tesseract_is_a_clear_error(monkeypatch, tmp_path):
    monkeypatch.setenv("SSMPC_TESSERACT", str(tmp_path / "no-tesseract"))
    assert find_tesseract() is None
    with pytest.raises(OcrUnavailable, match="apt-get install tesseract-ocr"):
        read_lines(b"\x89PNG")


def _drawn(texts, size=(640, 240)):
    """PNG of light grey text on the viewer's dark grey, 14 px font: [(text, x, y)]."""
    from PIL import Image, ImageDraw, ImageFont

    im = Image.new("RGB", size, (13, 13, 13))
    draw = ImageDraw.Draw(im)
    font = ImageFont.load_default(size=14)
    for text, x, y in texts:
        draw.text((x, y), text, fill=(220, 220, 220), font=font)
    buf = io.BytesIO()
    im.save(buf, "PNG")
    return buf.getvalue()


def test_drawn_text_is_read_where_it_was_drawn():
    require(find_tesseract() is not None,
            "no tesseract on PATH (apt-get install tesseract-ocr, or set SSMPC_TESSERACT)")
    png = _drawn([("log10 J (eq. 4.6)", 28, 8), ("active model", 300, 120)])
    lines = read_lines(png, OcrSettings(upscale=2))
    (j,) = find_phrase(lines, "log10 J (eq. 4.6)")
    (m,) = find_phrase(lines, "active model")
    # drawn from x 28 and 300; a 14 px font's letters within ~16 px of the y drawn at
    assert abs(j[0] - 28) <= 3 and 6 <= j[1] <= 14 and j[3] <= 8 + 20
    assert abs(m[0] - 300) <= 3 and 118 <= m[1] <= 126 and m[3] <= 120 + 20
    assert find_phrase(lines, "events") == []


def test_not_an_image_is_a_clear_error():
    require(find_tesseract() is not None,
            "no tesseract on PATH (apt-get install tesseract-ocr, or set SSMPC_TESSERACT)")
    with pytest.raises(ValueError, match="not an image"):
        read_lines(b"this is not a PNG")
