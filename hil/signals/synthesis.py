"""Sampled synthesis of a hop schedule: one call, or an endless block-wise stream.

Sample ``n`` is the schedule evaluated at ``t_n = n / fs``: the value of the hop that sounds
at ``t_n`` (a sample exactly on a boundary belongs to the new hop, as in
:meth:`HopSchedule.locate`). Each hop is written as a rotation of a per-segment phasor table,

    a·cos(θ₀ + ω m + π k m²/fs²) = a·(cos θ₀ · C[m] − sin θ₀ · S[m]),

so the cost is two multiplies and a subtraction per sample and no transcendental function on
the hot path. ``θ₀`` and the tables depend only on the hop, never on how the span is cut into
blocks, so any chunking gives bit-identical output (the streaming contract).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Iterator

import numpy as np
from numpy.typing import DTypeLike, NDArray

from hil.errors import ConfigError
from hil.signals.schedule import TWO_PI, FloatArray, HopSchedule, HopTable

_TABLE_CACHE_SIZE = 64
#: Hops whose first samples are found at a time and kept (a stream reads consecutive spans).
HOP_WINDOW = 64

# Chirp tables depend on the hop's sub-sample offset δ. δ is quantised to this grid so that
# float noise in computed start times (≈1e-15 s after 10 s of signal) does not defeat the
# table cache; the phase error this allows is at most 2π·|k|·(DELTA_GRID_S/2)·T_hop, below
# 1e-7 rad for every preset (k = 2e5 Hz/s, T = 0.1 s on tank-board FMCW). Tone tables do not
# depend on δ at all, so HFC-CW synthesis is unaffected.
DELTA_GRID_S = 1e-12


class BlockSynthesizer:
    """Endless sampled synthesis of a schedule at ``fs_hz``.

    Parameters
    ----------
    schedule:
        What to synthesise.
    fs_hz:
        Sample rate, Hz.
    amplitude:
        Linear scale of the output (1.0 = unit-amplitude cosines).
    first_sample:
        Index of the first sample :meth:`read` returns (sample ``n`` is at ``n / fs`` s).

    Examples
    --------
    >>> from hil.signals.schedule import HopSchedule
    >>> sch = HopSchedule.from_segments("demo", [1000.0, 2000.0], [0, 1], 0.001)
    >>> syn = BlockSynthesizer(sch, 8000.0)
    >>> np.round(syn.read(4), 12).tolist()
    [1.0, 0.707106781187, 0.0, -0.707106781187]
    >>> syn.position
    4
    """

    def __init__(
        self,
        schedule: HopSchedule,
        fs_hz: float,
        *,
        amplitude: float = 1.0,
        first_sample: int = 0,
    ) -> None:
        if not (math.isfinite(fs_hz) and fs_hz > 0):
            raise ConfigError("fs_hz", fs_hz, "> 0 Hz")
        if not math.isfinite(amplitude):
            raise ConfigError("amplitude", amplitude, "a finite number")
        self.schedule = schedule
        self.fs_hz = float(fs_hz)
        self.amplitude = float(amplitude)
        self.position = int(first_sample)
        self._tables: OrderedDict[tuple[float, float, float], tuple[FloatArray, FloatArray]] = (
            OrderedDict()
        )
        self._scratch = np.empty(0)
        self._window: tuple[HopTable, NDArray[np.int64]] | None = None

    # -------------------------------------------------------------- public
    def read(self, n_samples: int, dtype: DTypeLike = np.float64) -> NDArray[np.floating]:
        """The next ``n_samples`` samples (shape ``(n_samples,)``) and advance the position."""
        out = self.render(self.position, n_samples, dtype)
        self.position += n_samples
        return out

    def blocks(self, block_size: int, n_blocks: int | None = None) -> Iterator[FloatArray]:
        """Yield consecutive blocks of ``block_size`` samples (endless if ``n_blocks`` is None)."""
        if block_size < 1:
            raise ConfigError("block_size", block_size, ">= 1 sample")
        count = 0
        while n_blocks is None or count < n_blocks:
            yield self.read(block_size).astype(np.float64, copy=False)
            count += 1

    def render(
        self, first_sample: int, n_samples: int, dtype: DTypeLike = np.float64
    ) -> NDArray[np.floating]:
        """Samples ``first_sample .. first_sample + n_samples − 1`` (no state change)."""
        if n_samples < 0:
            raise ConfigError("n_samples", n_samples, ">= 0")
        out = np.zeros(n_samples, dtype=np.float64)
        if n_samples == 0:
            return out.astype(dtype, copy=False)
        n_end = first_sample + n_samples
        hops, bounds = self._hop_window(first_sample, n_end)
        # The hops sounding in the span: from the one holding first_sample to the last that
        # starts before n_end (each sample is written by the hop whose samples hold it).
        first_hop = int(np.searchsorted(bounds, first_sample, side="right")) - 1
        end_hop = int(np.searchsorted(bounds, n_end, side="left"))
        for i in range(first_hop, end_hop):
            if hops.amplitude[i] == 0.0:
                continue
            h_first, h_end = int(bounds[i]), int(bounds[i + 1])
            lo = max(h_first, first_sample)
            hi = min(h_end, n_end)
            if hi <= lo:
                continue
            self._write_hop(out, lo - first_sample, lo - h_first, hi - lo, h_first, h_end, hops, i)
        if self.amplitude != 1.0:
            out *= self.amplitude
        return out.astype(dtype, copy=False)

    # -------------------------------------------------------------- internals
    def _hop_window(self, first_sample: int, n_end: int) -> tuple[HopTable, NDArray[np.int64]]:
        """Consecutive hops that cover samples ``first_sample … n_end − 1``, and the first
        sample of each (one more than the hops: the last hop's end). At least
        :data:`HOP_WINDOW` hops, kept for the next spans they cover; a hop's first sample
        does not depend on the window it is found in."""
        if self._window is not None:
            bounds = self._window[1]
            if bounds[0] <= first_sample and n_end <= bounds[-1]:
                return self._window
        fs = self.fs_hz
        span = self.schedule.hops_in_span(first_sample / fs, (n_end - 1) / fs + 0.5 / fs)
        # One more hop than the span, so every hop's end sample is known.
        hops = self.schedule.hops(int(span.index[0]), max(HOP_WINDOW, len(span)) + 1)
        self._window = (hops, self._first_samples(hops.start_s, hops.index))
        return self._window

    def _first_samples(self, starts: FloatArray, index: NDArray[np.int64]) -> NDArray[np.int64]:
        """First sample of each hop: the smallest n with locate(n/fs) >= hop, vectorised.

        Decided with the same arithmetic as :meth:`HopSchedule.locate`, so a sample on a
        boundary goes to the same hop in both the analytic and the sampled path.
        """
        guess = np.ceil(starts * self.fs_hz).astype(np.int64)
        cand = guess[:, None] + np.arange(-2, 3, dtype=np.int64)[None, :]
        where = self.schedule.locate(cand / self.fs_hz)
        return cand[np.arange(cand.shape[0]), np.argmax(where >= index[:, None], axis=1)]

    def _table(
        self, freq: float, chirp: float, delta: float, length: int
    ) -> tuple[FloatArray, FloatArray]:
        # Tone tables do not depend on the sub-sample offset δ (it only rotates θ₀).
        delta_q = round(delta / DELTA_GRID_S) * DELTA_GRID_S if chirp != 0.0 else 0.0
        key = (freq, chirp, delta_q)
        hit = self._tables.get(key)
        if hit is not None and hit[0].shape[0] >= length:
            self._tables.move_to_end(key)
            return hit
        m = np.arange(length, dtype=np.float64) / self.fs_hz
        ph = TWO_PI * ((freq + chirp * key[2]) * m + 0.5 * chirp * m * m)
        table = (np.cos(ph), np.sin(ph))
        self._tables[key] = table
        if len(self._tables) > _TABLE_CACHE_SIZE:
            self._tables.popitem(last=False)
        return table

    def _write_hop(
        self,
        out: FloatArray,
        out_lo: int,
        m_lo: int,
        count: int,
        h_first: int,
        h_end: int,
        hops: HopTable,
        i: int,
    ) -> None:
        start = float(hops.start_s[i])
        freq = float(hops.freq_hz[i])
        chirp = float(hops.chirp_hz_per_s[i])
        amp = float(hops.amplitude[i])
        delta = h_first / self.fs_hz - start  # sub-sample offset of the hop's first sample
        theta0 = float(hops.phase_rad[i]) + TWO_PI * (freq * delta + 0.5 * chirp * delta * delta)
        hop_len = h_end - h_first
        cos_t, sin_t = self._table(freq, chirp, delta, hop_len)
        c0 = amp * math.cos(theta0)
        s0 = amp * math.sin(theta0)
        seg = out[out_lo : out_lo + count]
        np.multiply(cos_t[m_lo : m_lo + count], c0, out=seg)
        if self._scratch.shape[0] < count:
            self._scratch = np.empty(count)
        tmp = self._scratch[:count]
        np.multiply(sin_t[m_lo : m_lo + count], s0, out=tmp)
        np.subtract(seg, tmp, out=seg)


def synthesize(
    schedule: HopSchedule,
    fs_hz: float,
    duration_s: float,
    *,
    amplitude: float = 1.0,
    dtype: DTypeLike = np.float64,
) -> NDArray[np.floating]:
    """``round(duration_s·fs)`` samples of the schedule from t = 0, shape ``(N,)``.

    >>> from hil.signals.waveforms import WaveformSpec, build_schedule
    >>> x = synthesize(build_schedule(WaveformSpec()), 100_000.0, 0.5)
    >>> x.shape, float(np.max(np.abs(x))) <= 1.0
    ((50000,), True)
    """
    if not (math.isfinite(duration_s) and duration_s >= 0):
        raise ConfigError("duration_s", duration_s, ">= 0 s", "give a non-negative --duration")
    n = int(round(duration_s * fs_hz))
    return BlockSynthesizer(schedule, fs_hz, amplitude=amplitude).render(0, n, dtype)
