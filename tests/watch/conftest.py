"""Shared fixtures of the watch tests: a recording writer on an injected clock, with the
built-in simulated tank's experiment file (its geometry gives the truth)."""

from __future__ import annotations

import importlib.util
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from hil.estimation.base import Estimate
from hil.experiments.experiment import DEFAULT_EXPERIMENT
from hil.recording.records import ReceiverSetup
from hil.recording.writer import RunWriter
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule_file import schedule_document

#: Longest wait for a DOM condition in the browser tests, s (generous: both cores may be busy).
WAIT_S = 60.0

FS = 100_000.0
ORIGIN = 1000
"""Board sample index of the receiver's t = 0 in the test recordings."""


class FakeClock:
    """A monotonic clock the test advances (the writer flushes only when told)."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def estimate(i: int, range_m: float = 8.5, speed_mps: float = 1.5) -> Estimate:
    """The ``i``-th test estimate: one per 10 ms hop, t = 0.5 s + i·10 ms."""
    t = 0.5 + 0.01 * i
    return Estimate(
        t_s=t,
        range_m=range_m,
        speed_mps=speed_mps,
        hop_index=i,
        score=0.9,
        snr_db=12.0,
        alpha=1.0,
        t_tx_s=t - 2 * range_m / 1482.0,
        codeword=i % 7,
        receiver="gcas",
    )


@dataclass
class Recorder:
    """A recording being written: its ``writer``, ``path``, sample rate ``fs`` (Hz), the
    receiver's origin board sample ``origin`` and the test estimates' factory."""

    writer: RunWriter
    path: Path
    fs: float
    origin: int
    estimate: Callable[..., Estimate]


@pytest.fixture
def recorder(tmp_path: Path) -> Iterator[Recorder]:
    """A fresh writer of ``tmp_path/run.h5`` (closed after the test)."""
    spec = get_preset("att").spec("random-cyclic")
    doc = schedule_document(check_design(spec), FS, 0.0, sound_speed_mps=1500.0)
    path = tmp_path / "run.h5"
    writer = RunWriter.create(
        path,
        fs_hz=FS,
        n_channels=1,
        dtype="int16",
        schedule_document=doc,
        receiver=ReceiverSetup("gcas", {"m_hops": 10}),
        experiment_toml=DEFAULT_EXPERIMENT,
        origin_sample=ORIGIN,
        clock=FakeClock(),
    )
    yield Recorder(writer, path, FS, ORIGIN, estimate)
    writer.close()


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="session")
def _chromium_session(require_system: Callable[[bool, str], None]) -> Iterator[Any]:
    """One headless chromium driven by selenium for every browser test of a worker: each
    start is a chromium and a chromedriver process (1-2 s of wall time on the 2-core
    development machine), and the tests share nothing a page keeps (each loads its own
    server's page, on its own port: its own origin)."""
    require_system(
        importlib.util.find_spec("selenium") is not None,
        "selenium is not installed (pip install '.[test]')",
    )
    require_system(_chromium() is not None, "chromium is not installed (apt-get install chromium)")
    require_system(
        shutil.which("chromedriver") is not None,
        "chromedriver is not installed (apt-get install chromium-driver)",
    )
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = str(_chromium())
    for arg in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--disable-gpu"):
        options.add_argument(arg)
    options.add_argument("--window-size=1400,1000")
    driver = webdriver.Chrome(service=Service(str(shutil.which("chromedriver"))), options=options)
    driver.set_page_load_timeout(WAIT_S)
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture
def browser(_chromium_session: Any) -> Iterator[Any]:
    """The headless chromium, as a fresh one is to a test: on a blank page, its console log
    emptied (what the previous test's page logged is not this test's), its window 1400 by
    1000; left on a blank page after the test (its page's polling stops)."""
    driver = _chromium_session
    driver.get("about:blank")
    driver.set_window_size(1400, 1000)
    driver.get_log("browser")  # reading the log empties it
    try:
        yield driver
    finally:
        driver.get("about:blank")
