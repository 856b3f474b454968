"""The reports' Markdown subset renders emphasis as a person reads it, never a literal asterisk."""

from __future__ import annotations

from bench.report.trial import markdown_to_html


def test_emphasis_bold_and_code_render_and_arithmetic_stays_text():
    md = ("# T\n\nHow well. *Tip error*: the distance; *Tracking gap*: the RMS. **Bold**, `code`, "
          "2 * 3 * 4 and a*b*c.\n")
    page = markdown_to_html(md, {}, "t")
    assert "<em>Tip error</em>" in page and "<em>Tracking gap</em>" in page
    assert "<b>Bold</b>" in page and "<code>code</code>" in page
    assert "2 * 3 * 4" in page and "a*b*c" in page
    assert "*Tip" not in page
