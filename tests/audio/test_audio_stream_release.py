"""Releasing a PortAudio stream with a bounded wait, and abandoning one that cannot be released.

The whole path on a JACK server that goes away mid-run is the every-device suite's JACK
lost-mid-run case (tests/experiments/test_live_run_on_every_device.py)."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import threading
from collections.abc import Callable

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hil.devices.audio.stream_release import (
    RELEASE_FLOOR_S,
    RELEASE_GAPS,
    call_bounded,
    release_timeout_s,
)


@given(st.floats(min_value=0.0, max_value=60.0))
def test_the_release_wait_is_the_longest_gap_times_its_factor_at_least_the_floor(
    gap_s: float,
) -> None:
    wait = release_timeout_s(gap_s)
    assert wait == max(RELEASE_FLOOR_S, RELEASE_GAPS * gap_s)
    assert wait >= RELEASE_FLOOR_S and wait >= RELEASE_GAPS * gap_s


def test_a_release_wait_golden_values() -> None:
    assert release_timeout_s(0.0) == 2.0
    assert release_timeout_s(0.0223) == pytest.approx(2.23)  # the longest gap measured at load 8
    assert release_timeout_s(0.2) == 20.0


def test_a_call_that_returns_is_done_and_its_error_is_raised_here() -> None:
    done: list[int] = []
    assert call_bounded(lambda: done.append(1), 60.0, "test release") is True
    assert done == [1]

    def fails() -> None:
        raise ValueError("PortAudio said no")

    with pytest.raises(ValueError, match="PortAudio said no"):
        call_bounded(fails, 60.0, "test release")


def test_a_call_that_does_not_return_is_left_on_its_daemon_thread() -> None:
    release = threading.Event()
    names: list[str] = []

    def blocks() -> None:
        names.append(threading.current_thread().name)
        release.wait(60.0)

    assert call_bounded(blocks, 0.01, "PortAudio closing") is False
    worker = next(t for t in threading.enumerate() if t.name == "PortAudio closing")
    assert worker.daemon and worker.is_alive() and names == ["PortAudio closing"]
    release.set()
    worker.join(60.0)
    assert not worker.is_alive()


ABANDON = textwrap.dedent(
    """
    import sounddevice as sd
    from hil.devices.audio.portaudio_backend import AudioUnavailableError, rescan_devices
    from hil.devices.audio.stream_release import abandon, abandoned_why

    real_terminate = sd._terminate

    def terminate():  # says whether sounddevice's exit handler terminated PortAudio
        print("PortAudio terminated at exit", flush=True)
        real_terminate()

    sd._terminate = terminate
    print("abandoned before:", abandoned_why())
    if ABANDON:
        abandon(object(), "the stream on 0 'system' (JACK): its host ended it")
        print("abandoned:", abandoned_why())
        try:
            rescan_devices()
        except AudioUnavailableError as exc:
            print(exc)
    """
)


@pytest.mark.slow
@pytest.mark.parametrize("abandon", [False, True])
def test_an_abandoned_stream_keeps_portaudio_from_terminating_and_rescanning(
    abandon: bool, require_system: Callable[[bool, str], None]
) -> None:
    """In its own process: abandoning a stream marks PortAudio in that process for good."""
    from hil.devices.audio import portaudio_available

    ok, why = portaudio_available()
    require_system(ok, f"PortAudio is not available: {why}")
    # No JACK server for its PortAudio to join: a JACK client left running at exit (as
    # PortAudio not terminated leaves it) can crash the interpreter's teardown.
    env = dict(os.environ, JACK_DEFAULT_SERVER=f"hil-none-{os.getpid()}", JACK_NO_START_SERVER="1")
    proc = subprocess.run(
        [sys.executable, "-c", f"ABANDON = {abandon}\n{ABANDON}"],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
        env=env,
    )
    lines = proc.stdout.splitlines()
    if not abandon:
        assert lines == ["abandoned before: None", "PortAudio terminated at exit"]
        return
    reason = "the stream on 0 'system' (JACK): its host ended it"
    assert lines == [
        "abandoned before: None",
        f"abandoned: {reason}",
        f"PortAudio cannot re-scan its devices in this process: it holds a stream it could not"
        f" release ({reason}); start a new process to use audio devices again",
    ]
    assert f"PortAudio stream abandoned: {reason}" in proc.stderr
