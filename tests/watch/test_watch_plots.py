"""The watch page's plots as a lab reads them, in a real headless chromium: tick labels that
read differently, time axes aligned pixel for pixel across the three plots (the codeword map
included), wheel zoom and drag on one time axis for all plots, a double-click back to the
whole run, and hover that names the point under the mouse. Every step waits on a DOM
condition (WebDriverWait), never on the wall clock."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from hil.recording.records import StageTelemetry
from hil.watch import WatchData, WatchServer

WAIT_S = 60.0
N = 30


def _estimate(recorder: Any, i: int) -> Any:
    # Range falling 10 mm a hop; speed constant but for 1e-7 m/s of jitter: a span that
    # labels printed to 6 significant digits would all read "1.5".
    return recorder.estimate(i, range_m=8.5 - 0.01 * i, speed_mps=1.5 + 1e-7 * (i % 2))


def _plots(driver: Any) -> dict[str, Any]:
    result: dict[str, Any] = driver.execute_script("return watchPlots();")
    return result


@pytest.fixture
def page(browser: Any, recorder: Any) -> Any:
    """The page on a recording of ``N`` estimates, loaded; yields (driver, recorder)."""
    from selenium.webdriver.support.ui import WebDriverWait

    writer, origin = recorder.writer, recorder.origin
    writer.append_samples(origin, np.zeros(100_000, np.int16))
    for k in range(6):
        writer.append_telemetry(StageTelemetry(0.2 * k, origin + 20_000 * k, -2.0, -1.5, "Run"))
    writer.append_estimates([_estimate(recorder, i) for i in range(N)])
    writer.flush()
    server = WatchServer(WatchData.open(recorder.path)).start()
    try:
        browser.get(server.url)
        WebDriverWait(browser, WAIT_S).until(
            lambda d: d.find_element("id", "estimate-count").text == str(N)
        )
        yield browser, recorder
    finally:
        server.close()


@pytest.mark.slow
def test_axes_read_once_each_and_line_up(page: Any) -> None:
    driver, _ = page
    plots = _plots(driver)["plots"]
    assert set(plots) == {"range-plot", "speed-plot", "map-plot"}
    for name, p in plots.items():
        labels = p["yLabels"]
        assert len(labels) >= 3, name
        assert len(set(labels)) == len(labels), (name, labels)  # no label twice
        assert len(set(p["xLabels"])) == len(p["xLabels"]), name
        # The tick labels stand clear of the axis title beside them.
        assert p["yLabelLeft"] > p["yTitleRight"], name
    speed = plots["speed-plot"]
    assert speed["y0"] < 1.5 < speed["y1"] and speed["y1"] - speed["y0"] >= 1.5e-3
    # One time axis: the same range on the same pixels in every plot, the map's too.
    first = plots["range-plot"]
    for p in plots.values():
        assert (p["L"], p["R"], p["W"]) == (first["L"], first["R"], first["W"])
        assert (p["x0"], p["x1"]) == (first["x0"], first["x1"])
        assert p["xLabels"] == first["xLabels"]
    assert first["x0"] <= 0.5 and first["x1"] >= 0.5 + 0.01 * (N - 1)
    assert [e for e in driver.get_log("browser") if e["level"] == "SEVERE"] == []


@pytest.mark.slow
def test_wheel_zooms_every_plot_a_double_click_follows_the_run_again(page: Any) -> None:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.actions.wheel_input import ScrollOrigin
    from selenium.webdriver.support.ui import WebDriverWait

    driver, recorder = page
    wait = WebDriverWait(driver, WAIT_S)
    before = _plots(driver)
    assert before["auto"]
    canvas = driver.find_element("id", "speed-plot")
    ActionChains(driver).scroll_from_origin(ScrollOrigin.from_element(canvas), 0, -300).perform()
    wait.until(lambda d: not _plots(d)["auto"])
    zoomed = _plots(driver)
    assert zoomed["x1"] - zoomed["x0"] < 0.9 * (before["x1"] - before["x0"])
    for p in zoomed["plots"].values():
        assert (p["x0"], p["x1"]) == (zoomed["x0"], zoomed["x1"])
    assert "zoomed to" in driver.find_element("id", "zoom-note").text

    # The run goes on: the zoomed view stays where the user put it.
    recorder.writer.append_estimates([_estimate(recorder, i) for i in range(N, N + 10)])
    recorder.writer.flush()
    wait.until(lambda d: d.find_element("id", "estimate-count").text == str(N + 10))
    still = _plots(driver)
    assert (still["x0"], still["x1"]) == (zoomed["x0"], zoomed["x1"])

    ActionChains(driver).double_click(canvas).perform()
    wait.until(lambda d: _plots(d)["auto"])
    wait.until(lambda d: _plots(d)["x1"] >= 0.5 + 0.01 * (N + 9))
    assert driver.find_element("id", "zoom-note").text == ""


@pytest.mark.slow
def test_hover_names_the_estimate_under_the_mouse(page: Any) -> None:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.support.ui import WebDriverWait

    driver, _ = page
    i = 3
    t, r = 0.5 + 0.01 * i, 8.5 - 0.01 * i
    dx, dy = driver.execute_script(f"return pointOffset('range-plot', {t}, {r});")
    canvas = driver.find_element("id", "range-plot")
    ActionChains(driver).move_to_element_with_offset(canvas, round(dx), round(dy)).perform()
    tip = driver.find_element("id", "tooltip")
    WebDriverWait(driver, WAIT_S).until(lambda d: tip.is_displayed())
    assert tip.text == (
        f"range {r:.3f} m at {t:.4f} s (estimate {i}: codeword {i % 7}, score 0.900, SNR 12.0 dB)"
    )
    ActionChains(driver).move_by_offset(0, 400).perform()  # off the plots
    WebDriverWait(driver, WAIT_S).until(lambda d: not tip.is_displayed())
