"""Shared by the browser tests (Debian's Chromium, headless, software WebGL).

* ``PAGE_TIMEOUT_MS``: how long a page may take to show something [ms].
* ``page`` (fixture): a Chromium page; a test module may override it (another viewport).
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from playwright.sync_api import Page

from bt_teleop.testing.harness import chromium_page

PAGE_TIMEOUT_MS = 90_000
"""Software WebGL on a busy machine is slow."""


@pytest.fixture
def page() -> Iterator[Page]:
    with chromium_page(timeout_ms=PAGE_TIMEOUT_MS) as tab:  # names the fix if Chromium is missing
        yield tab
