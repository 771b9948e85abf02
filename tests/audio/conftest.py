"""Fixtures of the audio tests: a private JACK dummy server for the real-backend tier.

``jack_server`` starts ``jackd --no-realtime -d dummy -r 192000 -p 256`` under a unique
server name (clients find it through ``JACK_DEFAULT_SERVER``), waits until ``jack_lsp``
answers, makes PortAudio re-scan its devices, and kills the server at the end of the session.
When jackd, the JACK tools or PortAudio are missing the tests skip with the reason, or fail
when ``HIL_REQUIRE_SYSTEM_DEPS=1`` (set by ``.ci/run``, which installs them).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

JACK_SAMPLERATE = 192000
JACK_PERIOD = 256
JACK_TOOLS = ("jackd", "jack_lsp", "jack_connect")
STARTUP_TIMEOUT_S = 60.0  # deadlock guard: jackd answers within a second on a quiet machine


@dataclass(frozen=True)
class JackServer:
    """A running JACK dummy server: its name, sample rate (Hz) and period (frames)."""

    name: str
    samplerate: int
    period: int


def _jack_answers(env: dict[str, str]) -> bool:
    try:
        proc = subprocess.run(
            ["jack_lsp"], env=env, capture_output=True, text=True, timeout=30, check=False
        )
    except subprocess.TimeoutExpired:
        return False  # a busy machine: ask again until STARTUP_TIMEOUT_S
    return proc.returncode == 0 and "system:playback_1" in proc.stdout


@pytest.fixture(scope="session")
def jack_server(require_system: Callable[[bool, str], None]) -> Iterator[JackServer]:
    """A private ``jackd -d dummy`` server for the whole session (killed at the end)."""
    missing = [tool for tool in JACK_TOOLS if shutil.which(tool) is None]
    require_system(
        not missing, f"JACK is not installed ({', '.join(missing)} missing; apt-get install jackd2)"
    )
    from hil.devices.audio import portaudio_available

    ok, why = portaudio_available()
    require_system(ok, f"PortAudio is not available: {why}")

    name = f"hil-test-{os.getpid()}-{uuid.uuid4().hex[:6]}"
    saved = {k: os.environ.get(k) for k in _JACK_ENV}
    os.environ.update(
        JACK_DEFAULT_SERVER=name,
        JACK_NO_START_SERVER="1",  # a client must never auto-start a server of its own
        JACK_NO_AUDIO_RESERVATION="1",  # no D-Bus device reservation for the dummy driver
    )
    log = Path(tempfile.mkstemp(prefix="jackd-", suffix=".log")[1])
    with log.open("wb") as log_file:
        proc = subprocess.Popen(
            [
                "jackd",
                "--no-realtime",
                "-n",
                name,
                "-d",
                "dummy",
                "-r",
                str(JACK_SAMPLERATE),
                "-p",
                str(JACK_PERIOD),
            ],
            stdout=log_file,
            stderr=subprocess.STDOUT,
            env=os.environ.copy(),
        )
    try:
        deadline = time.monotonic() + STARTUP_TIMEOUT_S
        while not _jack_answers(os.environ.copy()):
            if proc.poll() is not None or time.monotonic() > deadline:
                tail = log.read_text(errors="replace")[-2000:]
                pytest.fail(f"jackd did not start within {STARTUP_TIMEOUT_S} s:\n{tail}")
            time.sleep(0.05)
        from hil.devices.audio import list_devices, rescan_devices

        rescan_devices()  # PortAudio enumerated devices at import, maybe before jackd ran
        has_jack = any(d.hostapi.startswith("JACK") for d in list_devices())
        require_system(has_jack, "this PortAudio build has no JACK host API")
        yield JackServer(name=name, samplerate=JACK_SAMPLERATE, period=JACK_PERIOD)
    finally:
        import sounddevice

        # Close PortAudio's JACK client before its server goes away, then re-open PortAudio
        # so later users of sounddevice in this process still work.
        sounddevice._terminate()
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value
        sounddevice._initialize()
        log.unlink(missing_ok=True)


_JACK_ENV = ("JACK_DEFAULT_SERVER", "JACK_NO_START_SERVER", "JACK_NO_AUDIO_RESERVATION")
