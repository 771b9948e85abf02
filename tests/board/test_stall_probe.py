"""The machine stall probe: window overlap against a written-out reference, a stall forced by
stopping a probe process, the merge of several probes, and its bad settings."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.acquisition.stall_probe import (
    MachineStalls,
    StallProbes,
    _merge,
    overlapping,
    probe,
    steal_s,
)
from hil.errors import ConfigError


def _stalls(start: list[float], end: list[float]) -> MachineStalls:
    n = len(start)
    return MachineStalls(
        np.array(start, dtype=np.float64),
        np.array(end, dtype=np.float64),
        np.zeros(n, dtype=np.int64),
        (0,),
        True,
        1000,
        0.0,
        100.0,
    )


def test_overlap_golden() -> None:
    s = _stalls([2.0, 1.0, 7.0], [2.5, 1.1, 9.0])  # unsorted on purpose
    got = s.overlapping(
        [0.0, 1.05, 1.2, 2.5, 5.0, 8.0, 9.5, np.nan], [0.99, 1.06, 1.9, 3.0, 6.9, 8.1, 10.0, 9.0]
    )
    assert got.tolist() == [False, True, False, True, False, True, False, False]
    # Only the long stall counts with min_stall_s = 1 s.
    long_only = s.overlapping([1.0, 2.0, 8.0], [1.1, 2.4, 8.5], min_stall_s=1.0)
    assert long_only.tolist() == [False, False, True]
    assert _stalls([], []).overlapping([0.0], [1.0]).tolist() == [False]


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(st.floats(0, 100), st.floats(0, 5)), max_size=12),
    st.lists(st.tuples(st.floats(0, 100), st.floats(0, 5)), min_size=1, max_size=12),
)
def test_overlap_matches_pairwise_reference(
    stalls: list[tuple[float, float]], windows: list[tuple[float, float]]
) -> None:
    s = _stalls([a for a, _ in stalls], [a + d for a, d in stalls])
    a = np.array([w for w, _ in windows])
    b = a + np.array([d for _, d in windows])
    pairs = list(zip(s.start, s.end, strict=True))
    want = [any(s0 <= bi and s1 >= ai for s0, s1 in pairs) for ai, bi in zip(a, b, strict=True)]
    assert s.overlapping(a, b).tolist() == want


def test_summary_figures() -> None:
    s = _stalls([1.0, 3.0, 4.0], [1.002, 3.0101, 4.006])
    summary = s.summary()
    assert summary["stalls"] == 3
    assert summary["stall_max_ms"] == pytest.approx(10.1, abs=1e-6)
    assert summary["stalls_over_5ms"] == 2
    assert summary["stalled_ms_per_s"] == pytest.approx(18.1 / 100.0, abs=1e-6)
    assert summary["steal_ms_per_s"] is None  # not measured
    stolen = MachineStalls(s.start, s.end, s.cpu, (0, 1), True, 10, 0.0, 100.0, steal_s=0.5)
    assert stolen.summary()["steal_ms_per_s"] == pytest.approx(2.5)  # 500 ms / 100 s / 2 CPUs


def test_overlapping_intervals_golden() -> None:
    got = overlapping([3.0, 1.0], [4.0, 2.0], [0.0, 2.0, 2.1, 3.5, 4.0], [0.9, 2.05, 2.9, 3.6, 9.0])
    assert got.tolist() == [False, True, False, True, True]
    assert overlapping([], [], [1.0], [2.0]).tolist() == [False]


@pytest.mark.skipif(not os.path.exists("/proc/stat"), reason="steal time is read from /proc/stat")
def test_steal_time_is_a_nondecreasing_counter() -> None:
    first = steal_s()
    second = steal_s()
    assert 0.0 <= first <= second


def test_merge_keeps_each_probes_cpu_and_the_common_interval() -> None:
    records = [
        {"cpu": 0, "realtime": True, "wakeups": 10, "t0": 1.0, "t1": 9.0, "threshold_s": 0.001,
         "start": [2.0], "end": [2.01]},
        {"cpu": 1, "realtime": False, "wakeups": 12, "t0": 1.5, "t1": 8.0, "threshold_s": 0.001,
         "start": [3.0, 4.0], "end": [3.1, 4.2]},
    ]  # fmt: skip
    m = _merge(records)
    assert m.cpu.tolist() == [0, 1, 1]
    assert m.cpus == (0, 1)
    assert m.realtime is False
    assert m.wakeups == 22
    assert (m.t0, m.t1) == (1.5, 8.0)
    assert np.isnan(m.steal_s)
    assert _merge(records, 0.25).steal_s == 0.25


def test_probe_in_process_counts_wakeups() -> None:
    record = probe(0.1, period_s=0.005, realtime=False)
    assert record["realtime"] is False
    assert 5 <= record["wakeups"] <= 21  # 0.1 s / 5 ms = 20, fewer if the machine stalls
    assert record["t1"] - record["t0"] >= 0.1


@pytest.mark.slow
def test_a_stopped_probe_reports_the_stall() -> None:
    """SIGSTOP holds the probe off its CPU for 0.3 s: it must report one stall covering it."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil.acquisition.stall_probe", "--cpu", "0", "--ready"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "ready"
        time.sleep(0.2)
        t_stop = time.monotonic()
        os.kill(proc.pid, signal.SIGSTOP)
        time.sleep(0.3)
        os.kill(proc.pid, signal.SIGCONT)
        t_cont = time.monotonic()
        time.sleep(0.1)
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    record = json.loads(out)
    assert record["cpu"] == 0
    d = np.array(record["end"]) - np.array(record["start"])
    k = int(np.argmax(d))
    assert 0.28 <= d[k] <= t_cont - t_stop + 0.05
    assert record["start"][k] <= t_stop + 0.01 and record["end"][k] >= t_cont - 0.01


@pytest.mark.slow
def test_probes_on_every_cpu() -> None:
    with StallProbes(period_s=0.002) as probes:
        time.sleep(0.3)
    result = probes.result
    assert result is not None
    assert result.cpus == tuple(sorted(os.sched_getaffinity(0)))
    # Each probe wakes about 150 times in 0.3 s; a loaded machine loses some.
    assert result.wakeups >= 50 * len(result.cpus)
    assert result.t1 - result.t0 >= 0.25


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"period_s": 0.0}, "period_s = 0.0 is not allowed: must be > 0 s"),
        ({"threshold_s": -1.0}, "threshold_s = -1.0 is not allowed: must be > 0 s"),
        ({"cpus": (10_000,)}, "cpu = 10000 is not allowed: must be one of the CPUs"),
        ({"cpus": ()}, "cpus = () is not allowed: must be at least one CPU"),
    ],
)
def test_bad_settings(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError) as error:
        StallProbes(**kwargs)  # type: ignore[arg-type]
    assert str(error.value).startswith(message)


def test_probe_process_rejects_a_cpu_it_may_not_use() -> None:
    proc = subprocess.run(
        [sys.executable, "-m", "hil.acquisition.stall_probe", "--cpu", "10000", "--seconds", "0"],
        capture_output=True,
        text=True,
        check=False,
        timeout=60,
    )
    assert proc.returncode != 0
    assert "cpu = 10000 is not allowed" in proc.stderr
