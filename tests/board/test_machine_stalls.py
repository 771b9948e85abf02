"""Machine stall probes: the probe loop on an injected clock, window overlap against a
written-out reference, a stall forced by stopping a probe process, probes that stop with
their parent, start and stop failures, and bad settings."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

# The stall probes are benchmark tools (benchmarks/), imported as the benchmarks import them.
BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))
PROBE = str(BENCHMARKS / "stall_probe.py")

from machine_stalls import (  # noqa: E402
    MachineStalls,
    StallProbes,
    _merge,
    overlapping,
    steal_s,
)
from stall_probe import run_probe  # noqa: E402

from hil.errors import ConfigError  # noqa: E402

CPU = min(os.sched_getaffinity(0))


def _stalls(start: list[float], end: list[float], cpus: tuple[int, ...] = (0,)) -> MachineStalls:
    n = len(start)
    return MachineStalls(
        np.array(start, dtype=np.float64),
        np.array(end, dtype=np.float64),
        np.zeros(n, dtype=np.int64),
        cpus,
        True,
        1000,
        0.0,
        100.0,
    )


class FakeClock:
    """A clock whose sleeps take exactly as long as asked, except the ``late`` ones (wake-up
    number → extra seconds)."""

    def __init__(self, late: dict[int, float]) -> None:
        self.t = 10.0
        self.calls = 0
        self.late = late

    def now(self) -> float:
        return self.t

    def sleep(self, s: float) -> None:
        self.calls += 1
        self.t += s + self.late.get(self.calls, 0.0)


# --------------------------------------------------------------------------- the probe loop
def test_probe_loop_records_exactly_the_late_wakeups() -> None:
    clock = FakeClock({3: 0.0005, 5: 0.004, 9: 0.0011})
    record = run_probe(
        0.05, period_s=0.002, threshold_s=0.001, realtime=False, now=clock.now, sleep=clock.sleep
    )
    assert record["realtime"] is False and record["cpu"] is None
    # Wake-up 3 is 0.5 ms late (under the threshold): not a stall. Wake-up 5 is due at
    # 10 + 0.0005 + 5 x 0.002 and comes 4 ms later; wake-up 9 comes 1.1 ms late.
    assert np.allclose(record["start"], [10.0105, 10.0225], atol=1e-12)
    assert np.allclose(record["end"], [10.0145, 10.0236], atol=1e-12)
    assert record["t0"] == 10.0 and record["t1"] >= 10.05
    assert record["wakeups"] == clock.calls


def test_probe_loop_stops_when_asked_and_leaves_signals_alone() -> None:
    clock = FakeClock({})
    before = signal.getsignal(signal.SIGTERM)
    record = run_probe(
        None,
        realtime=False,
        should_stop=lambda: clock.calls >= 7,
        now=clock.now,
        sleep=clock.sleep,
    )
    assert record["wakeups"] == 7
    assert record["start"] == [] and record["end"] == []
    assert signal.getsignal(signal.SIGTERM) is before


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"period_s": 0.0}, "period_s = 0.0 is not allowed: must be a finite time > 0 s"),
        ({"period_s": float("inf")}, "period_s = inf is not allowed"),
        ({"threshold_s": -1.0}, "threshold_s = -1.0 is not allowed"),
        ({"cpu": 10_000}, "cpu = 10000 is not allowed: must be one of the CPUs"),
    ],
)
def test_probe_loop_bad_settings(kwargs: dict[str, float], message: str) -> None:
    with pytest.raises(ConfigError) as error:
        run_probe(0.0, realtime=False, **kwargs)  # type: ignore[arg-type]
    assert str(error.value).startswith(message)


def test_probe_loop_bad_duration() -> None:
    with pytest.raises(ConfigError) as error:
        run_probe(-1.0, realtime=False)
    assert str(error.value).startswith("seconds = -1.0 is not allowed: must be a finite time")


# --------------------------------------------------------------------------- the figures
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


def test_overlapping_intervals_golden() -> None:
    got = overlapping([3.0, 1.0], [4.0, 2.0], [0.0, 2.0, 2.1, 3.5, 4.0], [0.9, 2.05, 2.9, 3.6, 9.0])
    assert got.tolist() == [False, True, False, True, True]
    assert overlapping([], [], [1.0], [2.0]).tolist() == [False]


@pytest.mark.slow
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
    assert stolen.summary()["stalled_ms_per_s"] == pytest.approx(18.1 / 200.0, abs=6e-4)


def test_between_cuts_stalls_and_span() -> None:
    s = _stalls([1.0, 3.0, 4.0, 9.0], [1.5, 3.5, 4.1, 9.2])
    w = s.between(1.2, 4.05, steal=0.25)
    assert w.start.tolist() == [1.2, 3.0, 4.0]
    assert w.end.tolist() == [1.5, 3.5, 4.05]
    assert (w.t0, w.t1, w.steal_s) == (1.2, 4.05, 0.25)
    assert w.wakeups == round(1000 * 2.85 / 100.0)
    with pytest.raises(ConfigError, match=r"t1 = 1\.0 is not allowed: must be >= t0 = 2\.0"):
        s.between(2.0, 1.0)


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
    with pytest.raises(ValueError, match="no probe records"):
        _merge([])


def test_steal_time_per_cpu(tmp_path: Path) -> None:
    stat = tmp_path / "stat"
    stat.write_text(
        "cpu  10 0 10 10 0 0 0 900 0 0\n"
        "cpu0 5 0 5 5 0 0 0 200 0 0\n"
        "cpu1 5 0 5 5 0 0 0 700 0 0\n"
        "intr 1 2 3\n"
    )
    hz = os.sysconf("SC_CLK_TCK")
    assert steal_s([0], stat) == pytest.approx(200 / hz)
    assert steal_s([0, 1], stat) == pytest.approx(900 / hz)
    assert steal_s(None, stat) == pytest.approx(900 / hz)
    assert np.isnan(steal_s([2], stat))
    assert np.isnan(steal_s(None, tmp_path / "missing"))


# --------------------------------------------------------------------------- probe processes
def _process_state(pid: int) -> str:
    """The one-letter state of process ``pid`` (``T``: stopped) from ``/proc``."""
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]


def _wait_for_state(pid: int, state: str, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s  # deadlock guard only
    while _process_state(pid) != state:
        assert time.monotonic() < deadline, f"process {pid} never reached state {state}"
        time.sleep(0.001)


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads processes from /proc")
def test_a_stopped_probe_reports_the_stall() -> None:
    """SIGSTOP holds the probe off its CPU for at least 0.3 s: it must report one stall that
    covers the whole time it was seen stopped. Causal bounds only (a busy machine may delay
    either signal), no figure on how long the stall took."""
    proc = subprocess.Popen(
        [sys.executable, PROBE, "--cpu", str(CPU), "--ready"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline().strip() == "ready"
        os.kill(proc.pid, signal.SIGSTOP)
        _wait_for_state(proc.pid, "T")
        seen_stopped = time.monotonic()
        time.sleep(0.3)  # the stall to report (a time to cover, not a wait for progress)
        cont_sent = time.monotonic()
        os.kill(proc.pid, signal.SIGCONT)
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0
    record = json.loads(out)
    assert record["cpu"] == CPU
    start, end = np.array(record["start"]), np.array(record["end"])
    # A stall starts when a wake-up falls due: at most one period after the probe last ran,
    # which was before it was seen stopped; it ends at a wake-up after SIGCONT was sent.
    covering = (start <= seen_stopped + record["period_s"]) & (end >= cont_sent)
    assert covering.sum() == 1, (seen_stopped, cont_sent, record["start"], record["end"])
    assert (end - start)[covering][0] >= cont_sent - seen_stopped - record["period_s"]


@pytest.mark.slow
def test_probes_on_every_cpu() -> None:
    with StallProbes(period_s=0.002) as probes:
        time.sleep(0.3)
    result = probes.result
    assert result is not None
    assert result.cpus == tuple(sorted(os.sched_getaffinity(0)))[:8]
    assert result.wakeups >= len(result.cpus)
    assert result.t1 > result.t0
    assert probes.stop() is result  # a second stop gives the same result


def _probe_pids() -> set[int]:
    """Pids of the processes running ``benchmarks/stall_probe.py``."""
    pids = set()
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes()
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if b"stall_probe.py" in cmdline and state != "Z":
            pids.add(int(entry.name))
    return pids


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads processes from /proc")
def test_probes_stop_when_their_caller_is_killed() -> None:
    before = _probe_pids()
    code = (
        "import sys, time\n"
        f"sys.path.insert(0, {str(BENCHMARKS)!r})\n"
        "from machine_stalls import StallProbes\n"
        f"p = StallProbes(cpus=({CPU},)).start()\n"
        "print('started', flush=True)\n"
        "time.sleep(60)\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    assert parent.stdout is not None
    assert parent.stdout.readline().strip() == "started"
    mine = _probe_pids() - before
    assert len(mine) == 1
    parent.kill()
    parent.wait()
    parent.stdout.close()
    deadline = time.monotonic() + 10.0
    while mine & _probe_pids() and time.monotonic() < deadline:
        time.sleep(0.05)
    left = mine & _probe_pids()
    for pid in left:  # do not leave an orphan running after a failure
        os.kill(pid, signal.SIGKILL)
    assert not left, "the probe outlived its killed caller"


class _Scripted(StallProbes):
    """Probes replaced by a scripted stand-in process."""

    script = ""

    def _command(self, cpu: int, out: Path) -> list[str]:
        return [sys.executable, "-c", self.script]


def test_a_probe_that_does_not_start_is_reported_and_nothing_is_left() -> None:
    probes = _Scripted(cpus=(CPU,))
    probes.script = "import sys; sys.exit(3)"
    with pytest.raises(RuntimeError, match=f"stall probe for CPU {CPU} did not start"):
        probes.start()
    assert probes._procs == [] and probes._dir is None


def test_a_probe_that_dies_is_reported_at_stop() -> None:
    probes = _Scripted(cpus=(CPU,))
    probes.script = "print('ready', flush=True); import sys; sys.exit(5)"
    probes.start()
    probes._procs[0][1].wait(timeout=30)  # gone before stop() signals it
    with pytest.raises(RuntimeError, match=f"CPU {CPU} exited with status 5"):
        probes.stop()
    assert probes._procs == [] and probes.result is None


def test_stop_before_start_says_so() -> None:
    with pytest.raises(RuntimeError, match="not running: call start"):
        StallProbes(cpus=(CPU,)).stop()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"period_s": 0.0}, "period_s = 0.0 is not allowed: must be a finite time > 0 s"),
        ({"threshold_s": -1.0}, "threshold_s = -1.0 is not allowed"),
        ({"cpus": (10_000,)}, "cpu = 10000 is not allowed: must be one of the CPUs"),
        ({"cpus": ()}, "cpus = () is not allowed: must be at least one CPU"),
        ({"cpus": (CPU, CPU)}, f"cpus = ({CPU}, {CPU}) is not allowed: must be each CPU once"),
    ],
)
def test_bad_settings(kwargs: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError) as error:
        StallProbes(**kwargs)  # type: ignore[arg-type]
    assert str(error.value).startswith(message)


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--cpu", "10000", "--seconds", "0"], "cpu = 10000 is not allowed"),
        (["--seconds", "-1"], "seconds = -1.0 is not allowed"),
        (["--period", "inf", "--seconds", "0"], "period_s = inf is not allowed"),
    ],
)
def test_probe_command_rejects_bad_arguments(args: list[str], message: str) -> None:
    proc = subprocess.run(
        [sys.executable, PROBE, "--no-realtime", *args],
        capture_output=True,
        text=True,
        check=False,
        timeout=60,
    )
    assert proc.returncode == 2
    assert message in proc.stderr
