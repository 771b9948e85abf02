"""Settings of a full-duplex audio stream, validated before any device is touched.

Device-independent ranges are checked when :class:`AudioSettings` is built; what depends on
the device (its channel counts, the sample rates it supports) is checked by the backend in
``open()``, still before the stream is created.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from hil.errors import ConfigError

SAMPLERATE_RANGE_HZ = (1000.0, 768000.0)
MAX_CHANNELS = 256
BLOCKSIZE_RANGE = (16, 65536)
LATENCY_RANGE_S = (0.0, 2.0)
LATENCY_PRESETS = ("low", "high")


@dataclass(frozen=True)
class AudioSettings:
    """Settings of one full-duplex stream; every field is checked on construction.

    Parameters
    ----------
    samplerate:
        Sample rate in Hz (the same for input and output), 1 kHz to 768 kHz. A JACK device
        only runs at its server's rate.
    channels_in, channels_out:
        Number of input (ADC) and output (DAC) channels, 1 to 256 each.
    blocksize:
        Frames per callback, 16 to 65536. Fixed on purpose: PortAudio's ``0`` (variable
        blocks) is refused because the loopback latency then depends on what the host picks.
    latency:
        Suggested device latency: ``"low"``, ``"high"`` or seconds in [0, 2]. Only a hint to
        the driver; the real loopback latency is measured (:mod:`hil.devices.audio.latency`).
    device:
        ``None`` (the default device), a device index, or a substring of the device name
        (case-insensitive, also matched against ``"<name>, <host API>"``).

    Examples
    --------
    >>> AudioSettings(samplerate=192000, channels_in=2, channels_out=2).blocksize
    256
    >>> AudioSettings(blocksize=0)
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: blocksize = 0 is not allowed: must be an integer in [16, 65536] \
frames; use a fixed block size such as 256 (0 = variable blocks is not supported: the \
loopback latency would change from run to run)
    """

    samplerate: float = 48000.0
    channels_in: int = 1
    channels_out: int = 1
    blocksize: int = 256
    latency: str | float = "low"
    device: str | int | None = None

    def __post_init__(self) -> None:
        lo, hi = SAMPLERATE_RANGE_HZ
        fs = self.samplerate
        if isinstance(fs, bool) or not isinstance(fs, int | float) or not lo <= fs <= hi:
            raise ConfigError(
                "samplerate",
                fs,
                f"a number of Hz in [{lo:g}, {hi:g}]",
                "use the rate the interface (or the JACK server) runs at, e.g. 48000",
            )
        for name in ("channels_in", "channels_out"):
            n = getattr(self, name)
            if not _is_int(n) or not 1 <= n <= MAX_CHANNELS:
                raise ConfigError(
                    name, n, f"an integer in [1, {MAX_CHANNELS}]", "count the connected channels"
                )
        lo_b, hi_b = BLOCKSIZE_RANGE
        if not _is_int(self.blocksize) or not lo_b <= self.blocksize <= hi_b:
            raise ConfigError(
                "blocksize",
                self.blocksize,
                f"an integer in [{lo_b}, {hi_b}] frames",
                "use a fixed block size such as 256 (0 = variable blocks is not supported: "
                "the loopback latency would change from run to run)",
            )
        lat = self.latency
        lo_l, hi_l = LATENCY_RANGE_S
        if isinstance(lat, str):
            ok = lat in LATENCY_PRESETS
        else:
            ok = (
                not isinstance(lat, bool)
                and isinstance(lat, int | float)
                and math.isfinite(lat)
                and lo_l <= lat <= hi_l
            )
        if not ok:
            raise ConfigError(
                "latency",
                lat,
                f"'low', 'high' or seconds in [{lo_l:g}, {hi_l:g}]",
                "it is only a hint to the driver; the loopback latency is measured anyway",
            )
        dev = self.device
        if not (dev is None or isinstance(dev, str) or (_is_int(dev) and dev >= 0)):
            raise ConfigError(
                "device",
                dev,
                "None, a device index >= 0 or a name substring",
                "list the devices with `python -m sounddevice`",
            )

    @property
    def block_duration_s(self) -> float:
        """Duration of one block in seconds (``blocksize / samplerate``).

        >>> AudioSettings(samplerate=48000, blocksize=480).block_duration_s
        0.01
        """
        return self.blocksize / float(self.samplerate)


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


class SettingsView:
    """Mixin for backends that keep an :class:`AudioSettings` as ``self.settings``: the
    stream properties every :class:`~hil.devices.audio.contract.DuplexBackend` exposes."""

    settings: AudioSettings

    @property
    def samplerate(self) -> float:
        """Sample rate (Hz)."""
        return float(self.settings.samplerate)

    @property
    def channels_in(self) -> int:
        """Number of input (ADC) channels."""
        return self.settings.channels_in

    @property
    def channels_out(self) -> int:
        """Number of output (DAC) channels."""
        return self.settings.channels_out

    @property
    def blocksize(self) -> int:
        """Frames per callback."""
        return self.settings.blocksize
