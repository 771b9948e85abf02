"""Make ``docs/watch.png``: ``hil watch --map`` in headless chromium during a simulated tank
run.

Runs ``hil tank-run`` (the built-in simulated tank) into a temporary folder, serves its
``run.h5`` with :class:`hil.watch.WatchServer` as soon as it is readable, opens the page in
headless chromium through selenium, waits until the page has seen the estimate count grow
(so the run is recording and the page following it) and at least ``--estimates`` estimates,
and saves the screenshot. Needs chromium, chromedriver and selenium (the test extra)::

    python docs/watch_screenshot.py [--out docs/watch.png] [--estimates 300]
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import WebDriverWait

from hil.errors import ConfigError
from hil.watch import WatchData, WatchServer


def _count(driver: webdriver.Chrome) -> int:
    return int(driver.find_element(By.ID, "estimate-count").text or 0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("watch.png"))
    parser.add_argument("--estimates", type=int, default=300, help="estimates shown first")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "run"
        cmd = [sys.executable, "-m", "hil.cli.main", "tank-run", "--out", str(folder), "--no-live"]
        run = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
        data = None
        while data is None and run.poll() is None:
            try:
                data = WatchData.open(folder / "run.h5", live_map=True)
            except ConfigError:
                time.sleep(0.2)  # not created yet, or not yet in SWMR mode
        if data is None:
            print("hil tank-run ended before its run.h5 was readable", file=sys.stderr)
            return 1
        options = webdriver.ChromeOptions()
        options.binary_location = str(shutil.which("chromium"))
        for arg in (
            "--headless=new",
            "--no-sandbox",
            "--hide-scrollbars",
            "--window-size=1400,1000",
        ):
            options.add_argument(arg)
        driver = webdriver.Chrome(
            service=Service(str(shutil.which("chromedriver"))), options=options
        )
        with WatchServer(data).start() as server:
            try:
                driver.get(server.url)
                wait = WebDriverWait(driver, 120)
                wait.until(lambda d: _count(d) > 0)
                first = _count(driver)
                wait.until(lambda d: _count(d) > first and _count(d) >= args.estimates)
                recording = run.poll() is None
                driver.save_screenshot(str(args.out))
                print(f"{args.out}: {_count(driver)} estimates, run still recording: {recording}")
            finally:
                driver.quit()
        run.wait()
    return 0


if __name__ == "__main__":
    sys.exit(main())
