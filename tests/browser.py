"""Headless Chromium for the page tests: Debian's ``chromium`` and ``chromium-driver`` through Selenium.

No browser is downloaded: the tests use the system binaries (``make test`` installs them) and skip, with
a one-line reason, where they are missing. Chromium runs with a fresh profile and every background
network feature off, so it neither stalls nor phones out on a closed network.
"""

from __future__ import annotations

import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

#: Where Debian puts the browser and its driver.
CHROMIUM = ("chromium", "chromium-browser")
CHROMEDRIVER = ("chromedriver",)
FLAGS = (
    "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    "--disable-dev-shm-usage", "--disable-default-apps", "--disable-extensions", "--hide-scrollbars",
)


def _which(names: tuple[str, ...]) -> str | None:
    return next((path for path in map(shutil.which, names) if path), None)


def missing_reason() -> str | None:
    """Why the browser tests cannot run here, or ``None``."""
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install -e '.[test]')"
    if _which(CHROMIUM) is None or _which(CHROMEDRIVER) is None:
        return "no chromium / chromedriver (apt-get install chromium chromium-driver; make test does)"
    return None


@contextmanager
def chromium(width: int = 1280, height: int = 800, downloads: Path | None = None) -> Iterator:
    """A headless Chromium WebDriver with browser console logging; skips the test when there is none."""
    reason = missing_reason()
    if reason:
        pytest.skip(reason)
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    profile = tempfile.mkdtemp(prefix="curbside-chromium-")
    options = webdriver.ChromeOptions()
    options.binary_location = _which(CHROMIUM)
    for flag in (*FLAGS, f"--user-data-dir={profile}", f"--window-size={width},{height}"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    if downloads is not None:
        options.add_experimental_option(
            "prefs", {"download.default_directory": str(downloads), "download.prompt_for_download": False}
        )
    driver = webdriver.Chrome(options=options, service=Service(_which(CHROMEDRIVER)))
    try:
        driver.set_page_load_timeout(60)
        yield driver
    finally:
        driver.quit()
        shutil.rmtree(profile, ignore_errors=True)


def console_errors(driver) -> list[str]:
    """Browser console messages at SEVERE level (errors, uncaught exceptions, failed loads) so far."""
    return [entry["message"] for entry in driver.get_log("browser") if entry["level"] == "SEVERE"]


def wait_for_mark(driver, name: str, timeout_s: float = 30.0) -> float:
    """Wait for a ``performance.mark(name)`` and return its time since navigation start, in ms."""
    from selenium.webdriver.support.ui import WebDriverWait

    script = f"const m = performance.getEntriesByName({name!r}); return m.length ? m[0].startTime : null;"
    return float(WebDriverWait(driver, timeout_s).until(lambda d: d.execute_script(script)))
