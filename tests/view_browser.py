"""Headless Chromium for the view's tests (tests/test_view.py): Debian's chromium and
chromedriver at /usr/bin, driven by Selenium without Selenium Manager (nothing downloaded),
WebGL on SwiftShader. Not a test module itself: it only holds the helpers (and has no tests)."""

from __future__ import annotations

import re
import shutil
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
CHROMEDRIVER = shutil.which("chromedriver") or "/usr/bin/chromedriver"
MISSING = [n for n, p in (("chromium", CHROMIUM), ("chromedriver", CHROMEDRIVER)) if not Path(p).is_file()]
WINDOW = (1280, 800)
FLAGS = ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
         f"--window-size={WINDOW[0]},{WINDOW[1]}")  # fmt: skip

T = TypeVar("T")


def start_chromium(profile: Path) -> Any:
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for flag in (*FLAGS, f"--user-data-dir={profile}"):
        opts.add_argument(flag)
    driver = webdriver.Chrome(service=Service(executable_path=CHROMEDRIVER), options=opts)
    driver.set_page_load_timeout(30)
    driver.set_script_timeout(10)
    return driver


def poll(what: str, probe: Callable[[], T | None], timeout_s: float, every_s: float = 0.25) -> T:
    """``probe()`` until it returns something not None; AssertionError naming ``what`` after
    ``timeout_s``. A probe the browser did not answer in time (Selenium's TimeoutException: a
    page busy with its first WebGL frames on SwiftShader, under load) counts as not yet."""
    from selenium.common.exceptions import TimeoutException

    end = time.monotonic() + timeout_s
    while True:
        try:
            got = probe()
        except TimeoutException:
            got = None
        if got is not None:
            return got
        if time.monotonic() > end:
            raise AssertionError(f"timed out after {timeout_s:.0f} s waiting for {what}")
        time.sleep(every_s)


def page_text(driver: Any) -> str:
    return str(driver.execute_script("return document.body ? document.body.innerText : ''"))


def screenshot(driver: Any, path: Path) -> np.ndarray:
    """The page as RGB pixels (H, W, 3), also saved to ``path``."""
    from PIL import Image

    driver.save_screenshot(str(path))
    return np.asarray(Image.open(path).convert("RGB")).astype(int)


def orange_pixels(rgb: np.ndarray, half_box: int = 60) -> int:
    """Pixels of the fuselage's signal orange (255, 102, 0), however lit, in a box about the
    centre of the canvas (where the follow camera looks): red strong, green a quarter to two
    thirds of it, little blue (the red reference ball and the grey discs are not this)."""
    h, w, _ = rgb.shape
    c = rgb[h // 2 - half_box : h // 2 + half_box, w // 2 - half_box : w // 2 + half_box]
    r, g, b = c[..., 0], c[..., 1], c[..., 2]
    return int(np.count_nonzero((r > 150) & (g > 0.25 * r) & (g < 0.65 * r) & (b < 0.45 * r)))


ERROR_RE = re.compile(r"tracking error: (≈?)([0-9.]+) m at t = ([0-9.]+) s")  # ≈: interpolated
TIME_RE = re.compile(r"\bt = ([0-9.]+) s\n")
