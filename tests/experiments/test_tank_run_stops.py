"""How a run stops, unit by unit: stop signals raise as Ctrl-C, a board link down past its
grace is lost (on an injected clock), every stop reason has its recording event, and a
lost device is named."""

from __future__ import annotations

import signal
import threading

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
