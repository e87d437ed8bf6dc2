"""The report in a real browser: headless Chromium, driven over the DevTools protocol
(``tests/chromium.py``). The page must load with no console message, no exception, no CSP
violation and no request besides itself; every plot must have a size on a desktop, on a phone-sized
screen (without the page scrolling sideways) and in print. Screenshots and a PDF are saved under
``test-artifacts/`` for people to look at.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from chromium import CHROMIUM, Chromium

from armbench.reports import render_index, render_report

pytestmark = pytest.mark.skipif(
    CHROMIUM is None or not hasattr(os, "posix_spawn"),
    reason="headless Chromium not installed (apt-get install chromium): the report is not "
           "checked in a browser")

RECORDS = Path(__file__).parent / "fixtures" / "records"
ARTIFACTS = Path(__file__).resolve().parents[1] / "test-artifacts"


@pytest.fixture(scope="module")
def browser(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Chromium]:
    chrome = Chromium(tmp_path_factory.mktemp("chromium"))
    try:
        chrome.open_page()
        yield chrome
    finally:
        chrome.close()


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The failing fixture run (every section, a baseline) with a traffic capture beside it."""
    runs = tmp_path_factory.mktemp("runs")
    run = runs / "failing"
    run.mkdir()
    shutil.copy(RECORDS / "failing.json", run / "results.json")
    lines = []
    for i in range(3000):
        error = "bytes outside a frame" if i % 500 == 7 else None
        lines.append({"t_s": round(i * 0.01, 3), "dir": "in" if i % 2 else "out",
                      "frame": "$31416,31416,31416,31416#", "error": error})
    (run / "capture.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    return render_report(run, run / "report.html")


def _check_plots(facts: dict[str, Any], expected: int) -> None:
    assert len(facts["svgs"]) == expected
    for w, h in facts["svgs"]:
        assert w > 100 and h > 50, facts["svgs"]
    assert facts["texts"] and sum(facts["texts"]) >= 0.9 * len(facts["texts"])


def test_report_in_chromium(browser: Chromium, report: Path) -> None:
    ARTIFACTS.mkdir(exist_ok=True)
    url = report.as_uri()
    browser.load(url)
    facts = browser.probe()
    assert facts["scripts"] == 0
    assert "Verdict: FAIL" in facts["verdict"]
    # the lead plot, accuracy 3, repeatability 2, startup-recovery 2, traffic 1
    _check_plots(facts, 9)
    for w, _ in facts["svgs"]:
        assert w <= facts["innerWidth"]
    assert facts["scrollWidth"] <= facts["innerWidth"]
    browser.screenshot(ARTIFACTS / "report-desktop.png")
    assert browser.problems() == []
    assert browser.requests() == [url]  # nothing but the page itself

    # a phone: the page never scrolls sideways (wide tables scroll inside their box)
    browser.viewport(390, 844, mobile=True)
    narrow = browser.probe()
    _check_plots(narrow, 9)
    assert narrow["scrollWidth"] <= narrow["innerWidth"], narrow
    assert narrow["overflowing"] == 0
    for w, _ in narrow["svgs"]:
        assert w <= narrow["innerWidth"]
    browser.screenshot(ARTIFACTS / "report-narrow.png", max_height=8000)

    # print: the navigation goes, the plots stay, a PDF comes out
    browser.viewport(794, 1123)
    browser.call("Emulation.setEmulatedMedia", {"media": "print"})
    printed = browser.probe()
    assert printed["nav"] == "none"
    _check_plots(printed, 9)
    assert printed["scrollWidth"] <= printed["innerWidth"]
    pdf = base64.b64decode(browser.call("Page.printToPDF", {"printBackground": True})["data"])
    assert pdf.startswith(b"%PDF") and len(pdf) > 50_000
    (ARTIFACTS / "report.pdf").write_bytes(pdf)
    browser.call("Emulation.setEmulatedMedia", {"media": ""})
    assert browser.problems() == []


def test_index_in_chromium(browser: Chromium, report: Path) -> None:
    runs = report.parent.parent
    for name in ("passing", "interrupted"):
        (runs / name).mkdir()
        shutil.copy(RECORDS / f"{name}.json", runs / name / "results.json")
    index = render_index(runs)
    browser.load(index.as_uri())
    facts = browser.probe()
    _check_plots(facts, index.read_text(encoding="utf-8").count("<svg "))
    assert facts["scrollWidth"] <= facts["innerWidth"]
    browser.screenshot(ARTIFACTS / "index-desktop.png")
    assert browser.problems() == []
    assert browser.requests() == [index.as_uri()]
