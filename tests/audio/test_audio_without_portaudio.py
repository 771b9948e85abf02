"""The audio package imports and simulates without PortAudio; the real backend says why not."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

from hil.devices.audio import AudioSettings, SoundDeviceDuplex
from hil.devices.audio.portaudio_backend import AudioUnavailableError

SCRIPT = textwrap.dedent(
    """
    import sys
    import numpy as np
    import hil.devices.audio as audio
    print("imported_sounddevice", "sounddevice" in sys.modules)
    sys.modules["sounddevice"] = None  # as if python-sounddevice / PortAudio were missing
    sim = audio.SimulatedDuplex(audio.AudioSettings(blocksize=64), io_delay_samples=64)
    print("sim_latency", audio.measure_loopback_latency(sim).latencies[0].samples)
    print("available", audio.portaudio_available()[0])
    """
)


@pytest.mark.slow
def test_package_imports_and_simulates_without_sounddevice() -> None:
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=60, check=True
    )
    assert proc.stdout.split("\n")[:3] == [
        "imported_sounddevice False",
        "sim_latency 64",
        "available False",
    ]


def test_real_backend_without_portaudio_names_the_package(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "sounddevice", None)
    backend = SoundDeviceDuplex(AudioSettings())
    with pytest.raises(AudioUnavailableError) as err:
        backend.open(lambda i, o, f, t, s: None)
    assert str(err.value).startswith("cannot load sounddevice (")
    assert "apt-get install libportaudio2" in str(err.value)
