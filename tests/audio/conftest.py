"""Fixtures of the audio tests: a private JACK dummy server for the real-backend tier.

``jack_server`` starts the product's :class:`~hil.devices.audio.jack_server.JackDummyServer`
(``jackd --no-realtime -d dummy -r 192000 -p 256``, asynchronous: a late client is an xrun,
as on a sound card) under a unique server name (clients find it through
``JACK_DEFAULT_SERVER``), which waits until ``jack_lsp`` answers; the fixture then makes
PortAudio re-scan its devices, and stops the server at the end of each module that uses it:
a running server and PortAudio's client of it wake 750 times a second (192 kHz, 256-frame
periods), about 5 % of a core between them with no stream open (measured on the 2-core
development machine), for as long as the server runs. When jackd,
the JACK tools or PortAudio are missing the tests skip with the reason, or fail when
``HIL_REQUIRE_SYSTEM_DEPS=1`` (set by ``.ci/run``, which installs them).
"""

from __future__ import annotations

import os
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import pytest

from hil.devices.audio.jack_ports import JackToolError
from hil.devices.audio.jack_server import DummyServerSettings, JackDummyServer, missing_tools
from hil.environment import environment

JACK_SAMPLERATE = 192000
JACK_PERIOD = 256


@dataclass(frozen=True)
class JackServer:
    """A running JACK dummy server: its name, sample rate (Hz) and period (frames)."""

    name: str
    samplerate: int
    period: int


@pytest.fixture(scope="module")
def jack_server(require_system: Callable[[bool, str], None]) -> Iterator[JackServer]:
    """A private ``jackd -d dummy`` server for one module's tests (stopped at its end)."""
    missing = missing_tools()
    require_system(
        not missing, f"JACK is not installed ({', '.join(missing)} missing; apt-get install jackd2)"
    )
    from hil.devices.audio import portaudio_available

    ok, why = portaudio_available()
    require_system(ok, f"PortAudio is not available: {why}")

    import sounddevice

    name = f"hil-test-{os.getpid()}-{uuid.uuid4().hex[:6]}"
    settings = DummyServerSettings(JACK_SAMPLERATE, JACK_PERIOD, synchronous=False)
    server = JackDummyServer(settings, name=name)
    jack_env = environment(
        JACK_DEFAULT_SERVER=name,
        JACK_NO_START_SERVER="1",  # a client must never auto-start a server of its own
        JACK_NO_AUDIO_RESERVATION="1",  # no D-Bus device reservation for the dummy driver
    )
    try:
        with jack_env:
            try:
                try:
                    server.start()
                except JackToolError as error:
                    pytest.fail(str(error))
                from hil.devices.audio import list_devices, rescan_devices

                rescan_devices()  # PortAudio enumerated devices at import, maybe before jackd ran
                has_jack = any(d.hostapi.startswith("JACK") for d in list_devices())
                require_system(has_jack, "this PortAudio build has no JACK host API")
                yield JackServer(name=name, samplerate=JACK_SAMPLERATE, period=JACK_PERIOD)
            finally:
                # Close PortAudio's JACK client before its server goes away.
                sounddevice._terminate()
                server.close()
    finally:
        # Re-open PortAudio (its environment restored) so later users of sounddevice in this
        # process still work.
        sounddevice._initialize()
