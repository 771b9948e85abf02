"""How a run stops, unit by unit: stop signals raise as Ctrl-C, a board link down past its
grace is lost (on an injected clock), every stop reason has its recording event, and a
lost device is named."""

from __future__ import annotations

import signal
import subprocess
import threading
from pathlib import Path

import pytest

from hil.acquisition.annotations import Annotation, AnnotationKind, AnnotationLog
from hil.experiments.live.stops import (
    LOST_AFTER_S,
    DeviceLostError,
    LinkWatch,
    RunInterrupted,
    StopSignals,
    stop_text,
)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_interrupt_as_ctrl_c_while_a_run_is_active(sig: signal.Signals) -> None:
    before = signal.getsignal(sig)
    with pytest.raises(KeyboardInterrupt) as info, StopSignals():
        signal.raise_signal(sig)
    assert isinstance(info.value, RunInterrupted) and info.value.signal_name == sig.name
    assert signal.getsignal(sig) is before  # restored


def test_a_stop_signal_during_the_safe_stop_is_noted_not_raised() -> None:
    signals = StopSignals().__enter__()
    try:
        signals.stopping()
        signal.raise_signal(signal.SIGTERM)  # would end the process if not handled
        assert signals.ignored == ["SIGTERM"]
    finally:
        signals.__exit__(None, None, None)


def test_outside_the_main_thread_stop_signals_change_nothing() -> None:
    before = signal.getsignal(signal.SIGTERM)
    seen: list[object] = []

    def body() -> None:
        with StopSignals():
            seen.append(signal.getsignal(signal.SIGTERM))

    thread = threading.Thread(target=body)
    thread.start()
    thread.join()
    assert seen == [before]


class _Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_a_link_down_past_its_grace_is_lost_and_a_reconnect_clears_it() -> None:
    log, clock = AnnotationLog(), _Clock()
    watch = LinkWatch(log, clock)
    assert watch.lost() is None
    log.add(Annotation(9000, AnnotationKind.DISCONNECT, 0, "EIO"))
    assert watch.lost() is None  # first seen now
    clock.t += LOST_AFTER_S - 1e-6
    assert watch.lost() is None
    log.add(Annotation(9000, AnnotationKind.RECONNECT, 1, "reconnected after 1 attempt(s)"))
    clock.t += 10.0
    assert watch.lost() is None  # came back: a USB glitch, not a lost board
    log.add(Annotation(20000, AnnotationKind.DISCONNECT, 0, "EIO again"))
    assert watch.lost() is None
    clock.t += LOST_AFTER_S
    assert watch.lost() == (
        "its link dropped at sample 20000 (EIO again) and has not come back for 0.50 s"
    )
    # Other annotations do not touch the link's state.
    log.add(Annotation(20000, AnnotationKind.GAP, 5, "gap"))
    assert watch.lost() is not None


def test_a_lost_device_is_named_with_what_to_check() -> None:
    lost = DeviceLostError("stage", "/dev/ttyUSB0", "OSError: [Errno 5] EIO", "its cable")
    assert str(lost) == "stage /dev/ttyUSB0 lost: OSError: [Errno 5] EIO; check its cable"
    assert (lost.device, lost.url) == ("stage", "/dev/ttyUSB0")


@pytest.mark.parametrize(
    ("interrupted", "error", "event"),
    [
        (False, "", ("note", "stop: completed")),
        (True, "interrupted (Ctrl-C)", ("alarm", "stop: interrupted (Ctrl-C)")),
        (True, "interrupted (SIGHUP)", ("alarm", "stop: interrupted (SIGHUP)")),
        (False, "RuntimeError: run.max_duration_s = 5 s exceeded",
         ("alarm", "stop: error: RuntimeError: run.max_duration_s = 5 s exceeded")),
    ],
)  # fmt: skip
def test_every_stop_reason_has_its_event(
    interrupted: bool, error: str, event: tuple[str, str]
) -> None:
    assert stop_text(interrupted=interrupted, error=error) == event


def test_a_second_ctrl_c_however_soon_is_noted_not_raised() -> None:
    # The first Ctrl-C starts the safe stop; the handler itself stops raising before it
    # raises, so a second one at any instant after it cannot break the safe stop off.
    with StopSignals() as signals:
        with pytest.raises(KeyboardInterrupt) as info:
            signal.raise_signal(signal.SIGINT)
        assert not isinstance(info.value, RunInterrupted)
        signal.raise_signal(signal.SIGINT)
        signal.raise_signal(signal.SIGTERM)
        assert signals.ignored == ["SIGINT", "SIGTERM"]


def test_hil_raises_on_stop_signals_from_its_first_instruction(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import hil.cli.main as cli

    before = signal.getsignal(signal.SIGTERM)

    def parser_hit_by_sigterm(load: object = None) -> object:
        signal.raise_signal(signal.SIGTERM)  # would end the process by its default action
        raise AssertionError("not reached")

    monkeypatch.setattr(cli, "build_parser", parser_hit_by_sigterm)
    assert cli.main(["tank-run"]) == 130
    assert capsys.readouterr().err == "hil: interrupted (SIGTERM)\n"
    assert signal.getsignal(signal.SIGTERM) is before  # restored when main returns


def test_a_stop_signal_while_a_command_sets_up_ends_it_in_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import hil.cli.main as cli
    import hil.cli.tank_run as tank_run

    def setting_up(args: object) -> int:
        signal.raise_signal(signal.SIGHUP)
        raise AssertionError("not reached")

    monkeypatch.setattr(tank_run, "run", setting_up)
    assert cli.main(["tank-run"]) == 130
    assert capsys.readouterr().err == "hil tank-run: interrupted (SIGHUP)\n"


def _wait_for(path: Path, proc: subprocess.Popen[str]) -> None:
    """Until ``path`` exists (the run reached that phase) or the process ended."""
    import time

    while not path.exists():
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.01)


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # a background suite hands it ignored


@pytest.mark.slow
def test_two_ctrl_c_in_a_row_stop_the_run_once_and_safely(tmp_path: Path) -> None:
    import json
    import sys

    from hil.recording.reader import RunRecording

    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil.cli.main", "tank-run", "--virtual-time", "--no-live",
         "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint,
    )  # fmt: skip
    _wait_for(out / "run.h5", proc)  # recording: the board streams, the stage moves
    proc.send_signal(signal.SIGINT)
    proc.send_signal(signal.SIGINT)  # at once: during the safe stop the first started
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 130, err  # stopped early by Ctrl-C: its summary says so
    assert "Traceback" not in err
    assert err.endswith(
        f"hil tank-run: interrupted (Ctrl-C): the run stopped early and safely; {out} holds it"
        ' up to the stop (summary.json: "interrupted": true)\n'
    ), err
    summary = json.loads((out / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["error"] == "interrupted (Ctrl-C)"
    with RunRecording.open(out / "run.h5") as rec:
        last = rec.events()[-1]
    assert (last.kind, last.text) == ("alarm", "stop: interrupted (Ctrl-C)")
    # One stop, whichever phase each Ctrl-C reached (a second one in the safe stop is
    # noted in run.log as ignored; two inside the recording's creation act as one).
    assert (out / "run.log").read_text().count("run stopped: interrupted (Ctrl-C)") == 1


@pytest.mark.slow
def test_sigterm_while_the_run_sets_up_ends_it_in_one_line(tmp_path: Path) -> None:
    import sys

    out = tmp_path / "run"
    proc = subprocess.Popen(
        [sys.executable, "-m", "hil.cli.main", "tank-run", "--virtual-time", "--no-live",
         "--out", str(out)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    _wait_for(out / "run.log", proc)  # the folder claimed, the receiver being built
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=300)
    assert "Traceback" not in err
    if (out / "run.h5").exists():  # the signal came once the recording was made
        from hil.recording.reader import RunRecording

        with RunRecording.open(out / "run.h5") as rec:
            assert rec.events()[-1].text == "stop: interrupted (SIGTERM)"
        assert proc.returncode == 130
    else:
        assert proc.returncode == 130 and err.endswith("hil tank-run: interrupted (SIGTERM)\n")


def test_a_stop_inside_a_step_done_whole_acts_at_its_end() -> None:
    from hil.interrupts import stops_deferred

    done: list[str] = []
    with StopSignals() as signals:
        with pytest.raises(RunInterrupted) as info, stops_deferred():
            signal.raise_signal(signal.SIGTERM)
            done.append("the whole step")
        assert info.value.signal_name == "SIGTERM"
        assert signals.ignored == []
    assert done == ["the whole step"]


def test_ctrl_c_before_a_command_starts_ends_hil_in_one_line(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import hil.cli.main as cli

    # As in a terminal (a suite run in the background hands its process SIGINT ignored).
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:

        def parser_hit_by_ctrl_c(load: object = None) -> object:
            signal.raise_signal(signal.SIGINT)
            raise AssertionError("not reached")

        monkeypatch.setattr(cli, "build_parser", parser_hit_by_ctrl_c)
        assert cli.main(["estimate"]) == 130
    finally:
        signal.signal(signal.SIGINT, previous)
    assert capsys.readouterr().err == "hil: interrupted (Ctrl-C)\n"
