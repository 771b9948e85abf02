"""The watch page in a real headless browser (chromium through chromedriver and selenium):
it loads, follows a recording while the test's writer (or a tank run on virtual time)
appends to it, and highlights an alarm. Each step waits on a DOM condition (WebDriverWait),
never on the wall clock.

Skipped when chromium, chromedriver or selenium is missing; with HIL_REQUIRE_SYSTEM_DEPS=1
(.ci/run) that fails instead.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from hil.estimation.base import Estimate
from hil.experiments.experiment import DEFAULT_EXPERIMENT
from hil.recording.records import RunEvent, StageTelemetry
from hil.recording.writer import RunWriter
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


class _FlushGates:
    """:meth:`RunWriter.append_estimates` wrapped so that the run waits for the test at given
    numbers of estimates: at the first append that brings the run's estimates to
    ``gates[0]`` or more, the run's thread flushes the file (as the writer does by itself
    each second: every pending row written, readers see them), hands the test the count
    (:meth:`next_flush`) and waits until :meth:`go_on`; then the same at ``gates[1]``, and so
    on. Paused there, mid-pass, the file holds exactly that many estimates, whatever the
    machine's speed: what the page shows is checked at known instants of the run."""

    def __init__(self, gates: list[int]) -> None:
        self.gates = list(gates)
        self.flushed: queue.Queue[int] = queue.Queue()
        self._resume = threading.Semaphore(0)
        self._appended = 0

    def install(self, monkeypatch: pytest.MonkeyPatch) -> None:
        original = RunWriter.append_estimates

        def append_and_wait(writer: RunWriter, estimates: Iterable[Estimate]) -> None:
            batch = list(estimates)
            original(writer, batch)
            self._appended += len(batch)
            if self.gates and self._appended >= self.gates[0]:
                self.gates.pop(0)
                writer.flush()
                self.flushed.put(self._appended)
                self._resume.acquire()

        monkeypatch.setattr(RunWriter, "append_estimates", append_and_wait)

    def next_flush(self) -> int:
        """The estimates in the file at the run's next gate (the run waits there)."""
        return self.flushed.get(timeout=RUN_GUARD_S)

    def go_on(self) -> None:
        self._resume.release()

    def open_all(self) -> None:
        """No more gates, and a run waiting at one goes on (the test is ending)."""
        self.gates.clear()
        self._resume.release()


#: Deadlock guard (never asserted on): a short run on virtual time takes seconds of CPU.
RUN_GUARD_S = 600.0


@pytest.mark.slow
def test_page_follows_a_simulated_tank_run(
    browser: Any, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The built-in simulated tank's run (a short, slow pass) on virtual time in a thread of
    this process, as ``hil tank-run --virtual-time`` runs it (:func:`hil.experiments.api.run`:
    summary and figures written), while the page polls its run.h5. The run waits twice with
    its file flushed (:class:`_FlushGates`): at its 20th estimate, until the page has loaded
    and shows the estimates in the file; at its 60th, mid-pass, until the page shows the
    count grown to what the file then holds. At the end the page's count equals the finished
    recording's; the server's time–codeword map follows the samples and peaks at the true
    codeword where the truth says each boundary arrives."""
    from selenium.webdriver.support.ui import WebDriverWait

    from hil.experiments import api

    # A 1 m pass at 0.5 m/s with 0.2 m run-up and run-down, from 0.1 m off home.
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
    folder = tmp_path / "run"
    gates = _FlushGates([20, 60])
    gates.install(monkeypatch)
    stop = threading.Event()
    ended: list[Any] = []

    def run() -> None:
        try:
            ended.append(api.run(text, folder=folder, stop=stop, virtual_time=True)[1])
        except BaseException as exc:  # handed to the test's thread
            ended.append(exc)

    runner = threading.Thread(target=run, name="tank-run", daemon=True)
    runner.start()
    server = None
    try:
        first = gates.next_flush()  # the run waits: its file holds `first` estimates
        data = WatchData.open(folder / "run.h5", live_map=True)
        server = WatchServer(data).start()
        browser.get(server.url)
        wait = WebDriverWait(browser, WAIT_S)
        wait.until(lambda d: _text(d, "file") == "run.h5")
        wait.until(lambda d: _text(d, "estimate-count") == str(first))
        gates.go_on()
        grown = gates.next_flush()  # mid-run again, `grown` estimates in the file
        assert grown > first >= 20
        wait.until(lambda d: _text(d, "estimate-count") == str(grown))
        gates.go_on()
        runner.join(RUN_GUARD_S)
        assert not runner.is_alive(), f"the run did not end within {RUN_GUARD_S} s"
        (summary,) = ended
        assert isinstance(summary, dict), summary
        assert summary["error"] == "" and not summary["interrupted"]
        final = data.estimates(0)["total"]
        assert final == summary["estimates"] > grown
        wait.until(lambda d: _text(d, "estimate-count") == str(final))
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
        # The finished run's saved time–codeword map, shown once the run wrote it.
        wait.until(
            lambda d: d.execute_script(
                "const i = document.getElementById('map-img');"
                "return i.complete && i.naturalWidth > 0 && i.offsetParent !== null;"
            )
        )
    finally:
        if server is not None:
            server.close()
        stop.set()  # the test failed first: the run stops safely, as on Ctrl-C
        gates.open_all()
        runner.join(RUN_GUARD_S)
