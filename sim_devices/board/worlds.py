"""What the board's ADC captures, given what its DAC emits: the pluggable *world*.

The world contract
------------------
``world(dac_block, first_sample) -> adc_block``

``dac_block``
    float64 array of shape ``(n, dac_channels)``: the DAC output at board sample indices
    ``first_sample .. first_sample + n - 1``, in full-scale units (+-1.0 is full scale,
    after the DAC gain). Silence (zeros) where the DAC had nothing to play.
``first_sample``
    Board sample-clock index of row 0 (samples).
``adc_block``
    array of shape ``(n, k)``, full-scale units, at the *same* sample indices: what the ADC
    inputs see before the ADC gain. Column ``j`` feeds the ``j``-th enabled ADC channel;
    missing columns are silent and extra ones are ignored.

The board calls the world once per block, in sample order, with no gaps and no overlaps
(while streaming), so a world may keep state (delay lines, filters, a moving target): any
cut of the stream into blocks must give the same output as one call on the whole. A world
may define ``reset()``: the board calls it when a stream starts. The block-wise acoustic
channel (``sim_devices.acoustics``) plugs in here.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np
import numpy.typing as npt

from hil.errors import ConfigError

FloatArray = npt.NDArray[np.float64]


class World(Protocol):
    """Maps a DAC block to the ADC block over the same sample indices (module docstring)."""

    def __call__(self, dac_block: FloatArray, first_sample: int, /) -> npt.NDArray[np.floating]:
        """The ADC inputs (n, k) for the DAC output ``dac_block`` (n, dac_channels)."""
        ...


class SilentWorld:
    """Nothing reaches the ADC: every input is zero (an unplugged board).

    >>> SilentWorld()(np.ones((3, 2)), 0).tolist()
    [[0.0], [0.0], [0.0]]
    """

    def __call__(self, dac_block: FloatArray, first_sample: int, /) -> FloatArray:
        return np.zeros((dac_block.shape[0], 1))


class LoopbackWorld:
    """A cable from each DAC channel to the same ADC channel, ``delay_samples`` late.

    ADC input ``k`` at index ``i`` is ``gain * dac[k]`` at index ``i - delay_samples``;
    before the first DAC sample of a stream the cable is silent. Channels are matched by
    position (the k-th enabled DAC channel feeds the k-th enabled ADC channel).

    Parameters
    ----------
    delay_samples:
        Cable delay, samples (>= 0).
    gain:
        Linear amplitude factor (finite).
    monitor:
        Also tap DAC channel 0 into one more ADC input (after the DAC channels' own), at the
        same delay and unity gain: the DAC monitor a tank run measures its loopback latency
        on (its ADC input 2 with one DAC channel).

    Examples
    --------
    >>> world = LoopbackWorld(delay_samples=2, gain=0.5)
    >>> out = np.arange(1.0, 5.0).reshape(4, 1)
    >>> world(out, 0)[:, 0].tolist()
    [0.0, 0.0, 0.5, 1.0]
    >>> world(out, 4)[:, 0].tolist()
    [1.5, 2.0, 0.5, 1.0]
    >>> LoopbackWorld(delay_samples=1, gain=0.5, monitor=True)(out, 0).tolist()
    [[0.0, 0.0], [0.5, 1.0], [1.0, 2.0], [1.5, 3.0]]
    """

    def __init__(self, delay_samples: int = 0, gain: float = 1.0, *, monitor: bool = False) -> None:
        if isinstance(delay_samples, bool) or not isinstance(delay_samples, int | np.integer):
            raise ConfigError("delay_samples", delay_samples, "an integer >= 0 (samples)")
        if delay_samples < 0:
            raise ConfigError(
                "delay_samples", delay_samples, "an integer >= 0 (samples)", "a cable is causal"
            )
        if not np.isfinite(gain):
            raise ConfigError("gain", gain, "a finite number (linear)")
        self.delay_samples = int(delay_samples)
        self.gain = float(gain)
        self.monitor = bool(monitor)
        self._tail: FloatArray | None = None  # the last delay_samples DAC rows

    def reset(self) -> None:
        """Empty the cable: silence before the next DAC sample."""
        self._tail = None

    def __call__(self, dac_block: FloatArray, first_sample: int, /) -> FloatArray:
        n, channels = dac_block.shape
        d = self.delay_samples
        if self._tail is None or self._tail.shape[1] != channels:
            self._tail = np.zeros((d, channels))
        joined = np.concatenate((self._tail, dac_block)) if d else dac_block
        out = joined[:n] * self.gain if self.gain != 1.0 else joined[:n].copy()
        self._tail = joined[n:].copy() if d else self._tail
        if self.monitor:
            out = np.concatenate((out, joined[:n, :1]), axis=1)
        return out
