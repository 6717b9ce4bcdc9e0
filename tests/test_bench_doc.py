"""A bench's report replaces its page's table and keeps the page's earlier runs below it (``bench._doc``)."""

from bench._doc import EARLIER, save_report, with_earlier


def test_a_new_report_goes_on_top_and_the_page_before_stays_below_it(tmp_path):
    page = tmp_path / "docs" / "bench" / "seg.md"
    save_report(page, "# Segmentation benchmark\n\n| a | 1 |\n", date="2026-12-06")
    assert page.read_text() == "# Segmentation benchmark\n\n| a | 1 |\n"  # no page before: the report alone
    # notes written by hand under the table are part of the page
    page.write_text(page.read_text() + "\nRun at abc: why the figures moved.\n")
    save_report(page, "# Segmentation benchmark\n\n| a | 2 |\n", date="2026-12-07")
    text = page.read_text()
    assert text.startswith("# Segmentation benchmark\n\n| a | 2 |\n")
    assert text.count("# Segmentation benchmark") == 1  # the old title is not repeated
    assert EARLIER.format(date="2026-12-07") in text
    assert text.index("| a | 2 |") < text.index("| a | 1 |") < text.index("Run at abc")
    assert [p.name for p in page.parent.iterdir()] == ["seg.md"]  # written atomically: no temporary left


def test_an_empty_page_before_adds_no_heading():
    assert with_earlier("# T\n\nx", "", "2026-12-07") == "# T\n\nx\n"
    assert with_earlier("# T\n\nx", None, "2026-12-07") == "# T\n\nx\n"
