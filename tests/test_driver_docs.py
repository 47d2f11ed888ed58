"""Each page in docs/robots/ has its first-session checklist and explains every driver error."""

from __future__ import annotations

import importlib
from pathlib import Path

import pytest

DOCS = Path(__file__).resolve().parent.parent / "docs" / "robots"
PAGES = {
    "aubo.md": ["robots.drivers.aubo"],
    "cobotta.md": ["robots.drivers.cobotta", "robots.drivers.bcap"],
    "franka.md": ["robots.drivers.franka"],
    "ur.md": ["robots.drivers.ur"],
    "realsense.md": ["robots.drivers.realsense"],
}
# Errors that several drivers share and that each page names in its own words.
SHARED = {"MotionTimeoutError", "ConnectionTimeoutError", "RobotDisconnectedError", "SafetyError"}


@pytest.mark.parametrize("page", sorted(PAGES))
def test_page_has_a_first_session_checklist(page):
    text = (DOCS / page).read_text()
    assert "## First session" in text, f"{page} lacks its 'First session' checklist"
    section = text.split("## First session", 1)[1].split("\n## ", 1)[0]
    assert "\n1. " in section and "\n3. " in section, f"{page}: the checklist has no numbered steps"


@pytest.mark.parametrize("page", sorted(PAGES))
def test_page_explains_every_error_its_driver_raises(page):
    text = (DOCS / page).read_text()
    errors = set()
    for name in PAGES[page]:
        module = importlib.import_module(name)
        errors |= {n for n in getattr(module, "__all__", ()) if n.endswith("Error")}
    undocumented = sorted(e for e in errors - SHARED if f"`{e}`" not in text)
    assert not undocumented, f"{page} does not say what {undocumented} mean"
