"""A headless chromium for the monitor's tests, benchmark and screenshots (docs/monitor.md
section 6): Debian's chromium driven through Debian's chromedriver by selenium, offline (no
background networking, no driver download), with a fresh profile each time."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

CHROMIUM = "/usr/bin/chromium"
CHROMEDRIVER = "/usr/bin/chromedriver"
FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-dev-shm-usage", "--window-size=1600,1500")


def missing() -> str:
    """Why no browser can be driven here ('' if one can)."""
    for path in (CHROMIUM, CHROMEDRIVER):
        if not Path(path).exists():
            return f"{path} is not installed (Debian: apt-get install chromium chromium-driver)"
    try:
        import selenium  # noqa: F401
    except ImportError:
        return "selenium is not installed (pip install 'hsio[test]')"
    return ""


class Browser:
    """A headless chromium session; ``driver`` is the selenium WebDriver."""

    def __init__(self, width: int = 1600, height: int = 1500, nice: int = 0):
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service

        self.profile = tempfile.mkdtemp(prefix="hsio-chromium-")
        options = webdriver.ChromeOptions()
        options.binary_location = CHROMIUM
        for flag in FLAGS:
            options.add_argument(flag)
        options.add_argument(f"--window-size={width},{height}")
        options.add_argument(f"--user-data-dir={self.profile}")
        options.unhandled_prompt_behavior = "ignore"  # a confirm dialog waits for the caller's answer
        try:
            # ``nice``: the browser (and its driver) below the priority of a run on the same machine.
            popen = {"preexec_fn": (lambda: os.nice(nice))} if nice else {}
            service = Service(executable_path=CHROMEDRIVER, popen_kw=popen)
            self.driver = webdriver.Chrome(service=service, options=options)
        except Exception:
            shutil.rmtree(self.profile, ignore_errors=True)
            raise
        self.driver.set_page_load_timeout(30)

    def model(self, name: str, expression: str):
        """``expression`` (JavaScript, with ``m`` the page's Bokeh model called ``name``) in the
        browser; None until the document has arrived."""
        return self.driver.execute_script(
            "const d = (window.Bokeh && Bokeh.documents.length) ? Bokeh.documents[0] : null;"
            f"const m = d ? d.get_model_by_name({name!r}) : null;"
            f"if (!m) return null; return {expression};")

    def close(self) -> None:
        try:
            self.driver.quit()
        finally:
            shutil.rmtree(self.profile, ignore_errors=True)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
