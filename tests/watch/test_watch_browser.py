"""The watch page in a real headless browser (chromium through chromedriver and selenium):
it loads, follows a recording while the test's writer appends to it, and highlights an
alarm. Each step waits on a DOM condition (WebDriverWait), never on the wall clock.

Skipped when chromium, chromedriver or selenium is missing; with HIL_REQUIRE_SYSTEM_DEPS=1
(.ci/run) that fails instead.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.experiments.experiment import DEFAULT_EXPERIMENT
from hil.recording.records import RunEvent, StageTelemetry
from hil.watch import WatchData, WatchServer

WAIT_S = 60.0
"""Longest wait for a DOM condition (generous: both cores may be busy)."""


def _text(driver: Any, element_id: str) -> str:
    from selenium.webdriver.common.by import By

    return str(driver.find_element(By.ID, element_id).text)


@pytest.mark.slow
def test_page_follows_a_recording_and_highlights_an_alarm(browser: Any, recorder: Any) -> None:
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import WebDriverWait

    wait = WebDriverWait(browser, WAIT_S)
    writer, origin = recorder.writer, recorder.origin
    writer.append_samples(origin, np.zeros(50_000, np.int16))
    for k in range(3):
        writer.append_telemetry(StageTelemetry(0.2 * k, origin + 20_000 * k, -2.0, -1.5, "Run"))
    writer.append_estimates([recorder.estimate(i) for i in range(5)])
    writer.flush()

    server = WatchServer(WatchData.open(recorder.path)).start()
    try:
        browser.get(server.url)
        assert browser.title == "hil watch"
        wait.until(lambda d: _text(d, "estimate-count") == "5")
        assert _text(browser, "file") == "run.h5"
        assert _text(browser, "stage-state") == "Run"
        assert _text(browser, "alarm-count") == "0"
        assert browser.find_elements(By.CSS_SELECTOR, "#events li.alarm") == []
        assert not browser.find_element(By.ID, "error").is_displayed()

        # The run goes on: more samples, estimates and an alarm, flushed as the writer does.
        writer.append_samples(origin + 50_000, np.zeros(50_000, np.int16))
        writer.append_estimates([recorder.estimate(i) for i in range(5, 12)])
        writer.append_event(RunEvent("alarm", origin + 80_000, 0, "watchdog: host silent"))
        writer.flush()
        wait.until(lambda d: _text(d, "estimate-count") == "12")
        wait.until(lambda d: d.find_elements(By.CSS_SELECTOR, "#events li.alarm"))
        alarm = browser.find_element(By.CSS_SELECTOR, "#events li.alarm")
        assert "ALARM" in alarm.text and "watchdog: host silent" in alarm.text
        assert alarm.value_of_css_property("background-color") == "rgba(255, 221, 221, 1)"
        assert _text(browser, "alarm-count") == "1"
        # Each table is refreshed on its own (SWMR): the samples may show a poll later.
        wait.until(lambda d: _text(d, "board-recorded") == "1.00 s (100000 samples)")
        # The page's own copy of the estimates: every row once, in order.
        times = browser.execute_script("return est.t;")
        assert times == pytest.approx([0.5 + 0.01 * i for i in range(12)])
        # Dots coloured per track: these estimates are on no confirmed track (grey).
        assert browser.execute_script("return est.key;") == [-1] * 12
        assert browser.execute_script(
            "return [0, 1, 9, -1].map(keyColour).concat([estimateColour(0, 'base')]);"
        ) == ["#1f77b4", "#ff7f0e", "#ff7f0e", "#999999", "#999999"]

        # The recording lost under the running server: the page says so in its banner.
        server.data.close()
        wait.until(lambda d: d.find_element(By.ID, "error").is_displayed())
        assert _text(browser, "error").startswith(f"{recorder.path} cannot be read: ")
    finally:
        server.close()


def _watchable(h5: Path) -> WatchData | None:
    """The live recording opened for watching, or None while ``hil tank-run`` has not yet
    created it in SWMR mode (the file appears before its groups are written)."""
    if not h5.exists():
        return None
    try:
        return WatchData.open(h5, live_map=True)
    except ConfigError:
        return None


@pytest.mark.slow
def test_page_follows_a_simulated_tank_run(browser: Any, tmp_path: Path) -> None:
    """``hil tank-run`` on the built-in simulated tank (a short, slow pass: seconds of
    estimates to watch) while the page polls its run.h5: the count grows during the run and
    ends equal to the finished recording's; the server's time–codeword map follows the
    samples and peaks at the true codeword where the truth says each boundary arrives."""
    from selenium.webdriver.support.ui import WebDriverWait

    exp_file = tmp_path / "slow.toml"
    # A 1 m pass at 0.5 m/s with 0.2 m run-up and run-down, from 0.1 m off home: no
    # positioning out to a run-up further away, seconds of estimates to watch.
    text = DEFAULT_EXPERIMENT
    for old, new in (
        ("start_m = -2.0", "start_m = -0.3"),
        ("end_m = -5.0", "end_m = -1.3"),
        ("speed_mps = 1.5", "speed_mps = 0.5"),
        ("run_up_m = 0.6", "run_up_m = 0.2"),
        ("run_down_m = 0.6", "run_down_m = 0.2"),
    ):
        assert old in text, old
        text = text.replace(old, new)
    exp_file.write_text(text)
    folder = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil.cli.main", "tank-run", str(exp_file), "--out", str(folder),
         "--no-live"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    server = None
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and (data := _watchable(folder / "run.h5")) is None:
            time.sleep(0.2)
        assert data is not None, "hil tank-run wrote no readable run.h5 within 120 s"
        server = WatchServer(data).start()
        browser.get(server.url)
        wait = WebDriverWait(browser, WAIT_S)
        wait.until(lambda d: _text(d, "file") == "run.h5")
        first = int(_text(browser, "estimate-count"))
        wait.until(lambda d: int(_text(d, "estimate-count")) > first)
        assert proc.wait(timeout=300) == 0
        final = data.estimates(0)["total"]
        wait.until(lambda d: _text(d, "estimate-count") == str(final))
        assert final > first
        assert _text(browser, "experiment") == "experiment sim-towed-pass"
        assert _text(browser, "stage-state") == "IDLE"
        # The map computed in the server, drawn on the page, covers the whole recording.
        assert data.live_map is not None
        end_s = data.state()["board"]["end_t_s"]
        wait.until(lambda d: data.live_map.computed_to_s == pytest.approx(end_s))
        wait.until(lambda d: _text(d, "map-note").startswith("map computed from the samples"))
        m = data.codeword_map()
        t, db = np.asarray(m["map"]["t_s"]), np.asarray(m["map"]["db"])
        arrival, codeword = np.asarray(m["boundary_t_s"]), np.asarray(m["boundary_codeword"])
        inside = (arrival > t[0] + 0.2) & (arrival < t[-1])  # after M = 10 hops of 10 ms
        col = np.searchsorted(t, arrival[inside], side="right") - 1
        assert np.mean(db[col].argmax(axis=1) == codeword[inside]) >= 0.8
        # The finished run's saved time–codeword map, shown once hil tank-run wrote it.
        wait.until(
            lambda d: d.execute_script(
                "const i = document.getElementById('map-img');"
                "return i.complete && i.naturalWidth > 0 && i.offsetParent !== null;"
            )
        )
    finally:
        if server is not None:
            server.close()
        if proc.poll() is None:  # the test failed first: leave nothing running
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
