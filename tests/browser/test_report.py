"""The report in chromium: no request but the file itself, every section visible, printable to PDF."""

from __future__ import annotations

from pathlib import Path

import pypdfium2
import pytest
from playwright.sync_api import Browser, expect

from backend.reports.template import SECTIONS
from tests.conftest import ARTIFACTS
from tests.services.test_report import report_template

pytestmark = [pytest.mark.slow, pytest.mark.browser]


@pytest.fixture(scope="module")
def report_file(demo_template: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return report_template(demo_template, tmp_path_factory) / "report.html"


def test_report_opens_offline_with_every_section_and_prints(browser: Browser, report_file: Path,
                                                            tmp_path: Path) -> None:
    context = browser.new_context(viewport={"width": 1200, "height": 900})
    try:
        page = context.new_page()
        requests: list[str] = []
        page.on("request", lambda request: requests.append(request.url))
        page.goto(report_file.as_uri())
        page.wait_for_load_state("load")
        for section_id, title in SECTIONS:
            heading = page.locator(f"section#{section_id} h2")
            heading.scroll_into_view_if_needed()
            expect(heading).to_have_text(title)
            expect(heading).to_be_visible()
        images = page.locator("img")
        assert images.count() == 9  # as test_report counts them
        for k in range(images.count()):  # every plot decoded and laid out
            assert images.nth(k).evaluate("img => img.complete && img.naturalWidth > 0")
        assert requests == [report_file.as_uri()]
        page.evaluate("window.scrollTo(0, 0)")
        page.screenshot(path=str(ARTIFACTS / "report.png"), full_page=True)
        page.emulate_media(media="print")
        assert page.locator("section#sensors").evaluate("s => getComputedStyle(s).breakBefore") == "page"
        pdf = tmp_path / "report.pdf"
        page.pdf(path=str(pdf), format="A4", print_background=True)
        document = pypdfium2.PdfDocument(str(pdf))
        try:
            assert len(document) >= len(SECTIONS)  # each section starts a page
            first_page = document[0].get_textpage().get_text_range()
            assert "Calibration report: demo" in first_page and "Overview" in first_page
        finally:
            document.close()
        assert requests == [report_file.as_uri()]
    finally:
        context.close()
