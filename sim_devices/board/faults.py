"""Faults the simulated board injects on demand, each one counted.

Byte faults damage the *next* ADC_DATA frame the board sends (so a test knows which sample
range is lost): the host's reader must drop it, count it, annotate the gap and resync at the
next delimiter. Sample faults act on the board's buffers; link faults on the session.

=====================  =====================================================================
fault                  effect
=====================  =====================================================================
``drop_bytes(n)``      ``n`` bytes vanish from the middle of the next ADC frame
``flip_bit()``         one bit of the next ADC frame is inverted (never producing 0x00)
``garbage(n)``         ``n`` random bytes (delimiters included) go out before the next frame
``adc_overrun(n)``     the ADC FIFO overflows: the next ``n`` captured samples are lost
``dac_underrun(n)``    the DAC FIFO loses ``n`` samples at its play head: silence is played
``disconnect()``       the link drops (in memory / USB: I/O fails until :meth:`replug`)
``expire_watchdog()``  the watchdog expires at the next tick whatever the keepalives
=====================  =====================================================================
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hil.errors import ConfigError


def _count(name: str, value: int, low: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise ConfigError(name, value, f"an integer >= {low}")
    return value


@dataclass
class FaultCounters:
    """How many times each fault fired (frames / events, not bytes)."""

    dropped_bytes: int = 0
    flipped_bits: int = 0
    garbage_bursts: int = 0
    adc_overruns: int = 0
    dac_underruns: int = 0
    disconnects: int = 0
    watchdog_expiries: int = 0


@dataclass
class FaultPlan:
    """Pending faults; the board consumes them as it runs. Seeded: ``FaultPlan(seed=7)``."""

    seed: int = 0
    counters: FaultCounters = field(default_factory=FaultCounters)
    _drop: list[int] = field(default_factory=list)
    _flips: int = 0
    _garbage: list[int] = field(default_factory=list)
    adc_overrun_samples: int = 0
    dac_underrun_samples: int = 0
    watchdog_now: bool = False
    unplugged: bool = False

    def __post_init__(self) -> None:
        self._rng = np.random.default_rng(self.seed)

    # --- requests ------------------------------------------------------------------------
    def drop_bytes(self, n: int = 16) -> None:
        """Remove ``n`` bytes from the middle of the next ADC frame."""
        self._drop.append(_count("drop_bytes.n", n))

    def flip_bit(self) -> None:
        """Invert one bit in the middle of the next ADC frame."""
        self._flips += 1

    def garbage(self, n: int = 64) -> None:
        """Send ``n`` random bytes right before the next ADC frame."""
        self._garbage.append(_count("garbage.n", n))

    def adc_overrun(self, samples: int = 1000) -> None:
        """Lose the next ``samples`` captured ADC samples (the FIFO overflowed)."""
        self.adc_overrun_samples += _count("adc_overrun.samples", samples)

    def dac_underrun(self, samples: int = 1000) -> None:
        """Lose ``samples`` queued DAC samples at the play head (silence is played)."""
        self.dac_underrun_samples += _count("dac_underrun.samples", samples)

    def disconnect(self) -> None:
        """Drop the link now; I/O fails until :meth:`replug`."""
        self.unplugged = True
        self.counters.disconnects += 1

    def replug(self) -> None:
        """Make the link available again (the host must reconnect)."""
        self.unplugged = False

    def expire_watchdog(self) -> None:
        """Expire the watchdog at the next tick."""
        self.watchdog_now = True

    # --- application (called by the board) -----------------------------------------------
    @property
    def frame_fault_pending(self) -> bool:
        """Whether the next ADC frame is to be damaged."""
        return bool(self._drop or self._flips or self._garbage)

    @property
    def any_pending(self) -> bool:
        """Whether any fault waits to be applied (or the link is unplugged)."""
        return bool(
            self.frame_fault_pending
            or self.adc_overrun_samples
            or self.dac_underrun_samples
            or self.watchdog_now
            or self.unplugged
        )

    def damage(self, wire: bytes) -> bytes:
        """The wire bytes of one ADC frame after the pending byte faults."""
        out = bytearray(wire)
        body = len(out) - 1  # never touch the final delimiter: resync happens there
        if self._drop:
            n = min(self._drop.pop(0), body - 2)
            start = (body - n) // 2
            del out[start : start + n]
            self.counters.dropped_bytes += 1
        elif self._flips:
            self._flips -= 1
            pos = body // 2
            bit = int(self._rng.integers(0, 8))
            while out[pos] ^ (1 << bit) == 0:
                bit = (bit + 1) % 8
            out[pos] ^= 1 << bit
            self.counters.flipped_bits += 1
        if self._garbage:
            n = self._garbage.pop(0)
            noise = self._rng.integers(0, 256, n, dtype=np.uint8).tobytes()
            out[:0] = noise
            self.counters.garbage_bursts += 1
        return bytes(out)
