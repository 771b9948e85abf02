"""Streaming echo with the path solved on a coarse grid: the fast form of an analytic echo.

:class:`~sim_devices.acoustics.echo.AnalyticEcho` solves the fixed-point delay for every
receive sample (about 1 µs per sample and path). The delay is smooth in time, so
:class:`GridEcho` solves it exactly only on a grid: intervals of ``h`` samples (a power of two,
about 4 ms by default: 4096 samples at 1 MHz, 512 at 100 kHz), aligned to absolute sample
indices ``n = k h``, solved at ``u = 0, ¼, ½, ¾`` of each (``u = (n − k h)/h``). In between:

- the delay ``d(t) = t − t_e(t)`` is a cubic Hermite through the node delays and their exact
  slopes ``d' = 1 − α`` (``α`` from the velocities, as the solver gives it);
- the path gain ``g`` (spreading, absorption, beam) is the quadratic through ``u = 0, ½, 1``,
  evaluated in float32 (relative error ``≈ H³ |g‴/g| / 72√3``, about 1e-8 for a tank path
  at 2.5 m and 2 m/s, ``H = h/fs``);
- the transmit is evaluated at ``t − d`` by
  :class:`~sim_devices.acoustics.transmit_eval.TransmitEvaluator` (float32 phase and cosine,
  error at most 3e-7 of the amplitude).

Error bound. For a smooth delay the Hermite error is ``≤ H⁴ max|d⁗| / 384``: about 1e-14 s
for tank geometry (2 m/s at 1 m, ``H`` = 4 ms). Every interval is *checked* against the
exact solution at its quarter points: when the interpolated delay at ``u = ¼, ½, ¾``, or its
slope at ``½`` times ``H``, is off by more than half of ``tolerance_s`` (default 1e-11 s), or
the gain at ``u = ¼, ¾`` by more than a third of ``gain_tolerance`` (default 1e-6, relative),
the whole interval is solved exactly per sample instead. That catches the corners of a
piecewise path (a jump of ``α`` inside an interval: the largest delay error is at most 1.5
times the larger midpoint error), steps of acceleration (1.03 times) and corners of the gain
alone (e.g. a leg that starts to lengthen while the total delay does not: at most 2.7 times
the larger quarter-point error). So the delay (timing) error stays below ``tolerance_s`` =
1e-11 s, a phase error of 1e-5 rad at 150 kHz, and the gain error below 1e-6. The solver's
own tolerance, 1e-13 s or four float64 ulps of ``t``, is the floor: the check threshold is
never below 16 ulps of ``t``.

Streaming. The grid is solved in fixed batches of ``prefetch_intervals`` intervals (batch
``b`` covers intervals ``b P … (b + 1) P − 1``; the solver is elementwise anyway), and every
sample is computed from its own interval's data with the same arithmetic whatever the block:
:meth:`GridEcho.block` returns the same samples, bit for bit, for any chunking. The paths'
trajectories are queried up to one batch (``P h`` samples, 66 ms at 1 MHz by default) after
the last sample read; a batch costs one solve call, so the look-ahead buys speed. A still path
(every trajectory ``still``, e.g. the direct blast of a fixed transducer, and a gain from the
geometry alone) has the same delay and gain at every time: its first batch, solved once, is
every batch's (the same values a solve of each would give).

:class:`EchoBank` renders several paths on one grid (a target's direct and tank-image echoes):
their batches are solved together by :func:`~sim_devices.acoustics.delay.solve_paths` and the
per-block arrays (:class:`SampleGrid`) are shared; each path is added to the block by compiled
loops (:meth:`GridEcho.add_render`, :mod:`~sim_devices.acoustics.echo_kernels`: the same bits
as :meth:`GridEcho.render`).

Example: against the exact per-sample solve, for a target closing at 2 m/s.

>>> from hil.signals.schedule import HopSchedule
>>> from sim_devices.acoustics.delay import TwoWayPath
>>> from sim_devices.acoustics.echo import AnalyticEcho
>>> from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed
>>> sch = HopSchedule.from_segments("demo", [140e3, 150e3], [0, 1], 0.005)
>>> path = TwoWayPath.monostatic(Fixed((0, 0, 0)), ConstantVelocity((3, 0, 0), (-2, 0, 0)), 1480)
>>> fast = GridEcho(sch, path, 1e6).block(0, 20000)
>>> exact = AnalyticEcho(sch, path, 1e6).block(0, 20000)
>>> bool(np.max(np.abs(fast - exact)) < 1e-6)
True
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from sim_devices.acoustics.delay import PathSolution, PropagationPath, solve_paths
from sim_devices.acoustics.echo import (
    AnalyticEcho,
    PathGain,
    TransmitWaveform,
    sample_times,
    unit_gain,
)
from sim_devices.acoustics.echo_kernels import (
    add_echo,
    gains_and_emission_times,
    transmit_phases,
)
from sim_devices.acoustics.trajectory import FloatArray
from sim_devices.acoustics.transmit_eval import TransmitEvaluator

#: Target grid spacing (s); the actual one is the nearest power-of-two number of samples.
DEFAULT_GRID_S = 4e-3
#: Largest delay (timing) error (s) of the interpolation; intervals that miss it are exact.
DEFAULT_TIMING_TOLERANCE_S = 1e-11
#: Largest relative error of the interpolated path gain; intervals that miss it are exact.
DEFAULT_GAIN_TOLERANCE = 1e-6
#: Intervals solved per batch (the look-ahead of trajectory queries, in grid intervals).
DEFAULT_PREFETCH_INTERVALS = 16

#: Samples rendered per pass (keeps the per-sample arrays in cache).
SUB_BLOCK = 16384

_EPS = float(np.finfo(np.float64).eps)


def grid_samples_for(fs_hz: float, grid_s: float = DEFAULT_GRID_S) -> int:
    """The power-of-two number of samples (>= 4) nearest to ``grid_s`` (s) at ``fs_hz`` (Hz).

    >>> grid_samples_for(1e6), grid_samples_for(100e3), grid_samples_for(192e3)
    (4096, 512, 1024)
    """
    return 1 << max(2, round(math.log2(max(4.0, grid_s * fs_hz))))


class _Batch:
    """Interval data of one batch: delay and gain polynomials and the exact-interval flags.

    For interval ``i`` and ``u`` in ``[0, 1)``: delay ``c0 + u (c1 + u (c2 + u c3))`` (s,
    float64), gain ``g0 + u (g1 + u g2)`` (float32); ``exact[i]`` means the interval is solved
    per sample.
    """

    def __init__(
        self, coeffs: FloatArray, gains: NDArray[np.float32], exact: NDArray[np.bool_]
    ) -> None:
        self.coeffs, self.gains, self.exact = coeffs, gains, exact


class GridEcho(AnalyticEcho):
    """An :class:`~sim_devices.acoustics.echo.AnalyticEcho` whose :meth:`block` interpolates the
    path between grid nodes (see the module docstring); :meth:`at_times` stays exact.

    Parameters as :class:`~sim_devices.acoustics.echo.AnalyticEcho`, plus ``grid_samples``
    (power of two >= 4; default :func:`grid_samples_for` the rate), ``tolerance_s`` (largest
    delay error, s), ``gain_tolerance`` (largest relative gain error) and
    ``prefetch_intervals`` (intervals solved per batch).
    """

    def __init__(
        self,
        waveform: TransmitWaveform,
        path: PropagationPath,
        fs_hz: float,
        *,
        t_start_s: float = 0.0,
        amplitude: float = 1.0,
        gain: PathGain = unit_gain,
        grid_samples: int | None = None,
        tolerance_s: float = DEFAULT_TIMING_TOLERANCE_S,
        gain_tolerance: float = DEFAULT_GAIN_TOLERANCE,
        prefetch_intervals: int = DEFAULT_PREFETCH_INTERVALS,
    ) -> None:
        super().__init__(waveform, path, fs_hz, t_start_s=t_start_s, amplitude=amplitude, gain=gain)
        h = grid_samples_for(self.fs_hz) if grid_samples is None else grid_samples
        if isinstance(h, bool) or int(h) != h or h < 4 or (int(h) & (int(h) - 1)):
            raise ConfigError("grid_samples", grid_samples, "a power of two >= 4", "e.g. 4096")
        if not (math.isfinite(tolerance_s) and tolerance_s > 0):
            raise ConfigError("tolerance_s", tolerance_s, "> 0 s", "1e-11 s is the default")
        if not (math.isfinite(gain_tolerance) and gain_tolerance > 0):
            raise ConfigError("gain_tolerance", gain_tolerance, "> 0", "1e-6 is the default")
        if int(prefetch_intervals) != prefetch_intervals or prefetch_intervals < 1:
            raise ConfigError("prefetch_intervals", prefetch_intervals, "an integer >= 1")
        self.grid_samples = int(h)
        self._shift = self.grid_samples.bit_length() - 1
        self.tolerance_s = float(tolerance_s)
        self.gain_tolerance = float(gain_tolerance)
        self.prefetch = int(prefetch_intervals)
        self.transmit = TransmitEvaluator(waveform)
        self._batches: dict[int, _Batch] = {}
        #: Number of intervals that failed the check and were solved per sample.
        self.exact_intervals = 0
        #: A still path (every trajectory ``still``, a gain from the geometry alone) has the
        #: same delay and gain at every time: its first batch serves every batch.
        self.still = _still_path(path) and (
            gain is unit_gain or bool(getattr(gain, "from_geometry", False))
        )
        self._still_batch: _Batch | None = None

    # ------------------------------------------------------------------ grid
    def batch_times(self, b: int) -> FloatArray:
        """Times (s) solved for batch ``b``: ``u = 0, ¼, ½, ¾`` of each interval, then the
        batch's end node, shape ``(4 P + 1,)``."""
        h, p = self.grid_samples, self.prefetch
        n = b * p * h + np.arange(4 * p + 1, dtype=np.int64) * (h // 4)
        return self.t_start_s + n / self.fs_hz

    def store_batch(self, b: int, sol: PathSolution) -> None:
        """Build batch ``b``'s interval data from the path solved at :meth:`batch_times`."""
        store_batches([self], b, [sol])

    def has_batch(self, b: int) -> bool:
        """Whether batch ``b`` is solved and held (a still path's is as soon as one is)."""
        if b not in self._batches and self._still_batch is not None:
            self._keep(b, self._still_batch)
        return b in self._batches

    def _keep(self, b: int, batch: _Batch) -> None:
        """Hold ``batch`` as batch ``b``."""
        self._batches[b] = batch
        self.exact_intervals += int(np.count_nonzero(batch.exact))
        if self.still and self._still_batch is None:
            self._still_batch = batch

    def _batch(self, b: int) -> _Batch:
        if not self.has_batch(b):
            self.store_batch(b, self.path.solve(self.batch_times(b)))
        return self._batches[b]

    def _interval_data(
        self, ka: int, kb: int
    ) -> tuple[FloatArray, NDArray[np.float32], NDArray[np.bool_]]:
        """Coefficients (4, m), gains (3, m) and exact flags (m,) of intervals ka … kb."""
        p = self.prefetch
        parts = [self._batch(b) for b in range(ka // p, kb // p + 1)]
        for old in [key for key in self._batches if key < ka // p]:
            del self._batches[old]  # streaming forward: earlier batches are done
        lo = ka - (ka // p) * p
        hi = lo + (kb - ka + 1)
        if len(parts) == 1:
            one = parts[0]
            return one.coeffs[:, lo:hi], one.gains[:, lo:hi], one.exact[lo:hi]
        coeffs = np.concatenate([q.coeffs for q in parts], axis=1)[:, lo:hi]
        gains = np.concatenate([q.gains for q in parts], axis=1)[:, lo:hi]
        exact = np.concatenate([q.exact for q in parts])[lo:hi]
        return coeffs, gains, exact

    def sample_grid(self, n0: int, count: int) -> SampleGrid:
        """The :class:`SampleGrid` of samples ``n0 … n0 + count − 1`` on this echo's grid."""
        return SampleGrid(n0, count, self.grid_samples, self.fs_hz, self.t_start_s)

    def delay_and_gain(self, n0: int, count: int) -> tuple[FloatArray, FloatArray]:
        """Interpolated delay (s) and path gain of samples ``n0 … n0 + count − 1``, ``(count,)``.

        The gain is computed in float32 (relative error about 1e-7).
        """
        d, g = self._delay_and_gain(self.sample_grid(n0, count))
        return d, g.astype(np.float64)

    def _delay_and_gain(self, grid: SampleGrid) -> tuple[FloatArray, NDArray[np.floating[Any]]]:
        if grid.count == 0:
            return np.zeros(0), np.zeros(0, dtype=np.float32)
        coeffs, gains, exact = self._interval_data(grid.ka, grid.kb)
        d = np.asarray(grid.polynomial(coeffs), dtype=np.float64)  # no copy: float64 already
        g = grid.polynomial(gains)
        for i in np.flatnonzero(exact):
            a, e = int(grid.offsets[i]), int(grid.offsets[i + 1])
            sol = self.path.solve(grid.t[a:e])
            d[a:e] = sol.delay_s
            g[a:e] = self.gain(sol)
        return d, g

    # ------------------------------------------------------------------ synthesis
    def render(self, grid: SampleGrid) -> NDArray[np.floating[Any]]:
        """Received samples of ``grid`` (shape ``(grid.count,)``, float32: the transmit and
        the gain are computed to float32 precision)."""
        d, g = self._delay_and_gain(grid)
        t_emit = np.subtract(grid.t, d, out=d)
        if self.amplitude != 1.0:
            g *= np.float32(self.amplitude)
        g *= self.transmit.at_sorted_times(t_emit)
        return g

    def add_render(self, grid: SampleGrid, out: FloatArray) -> None:
        """``out += render(grid)`` (``out`` float64, shape ``(grid.count,)``), the same bits:
        by compiled loops (:mod:`~sim_devices.acoustics.echo_kernels`) for a hop schedule
        and intervals all interpolated, else by :meth:`render`."""
        transmit = self.transmit
        if grid.count == 0 or transmit.schedule is None:
            out += self.render(grid)
            return
        coeffs, gains, exact = self._interval_data(grid.ka, grid.kb)
        if exact.any():
            out += self.render(grid)
            return
        # Contiguous copies (a few values an interval): one compiled form for every block.
        coeffs, gains = np.ascontiguousarray(coeffs), np.ascontiguousarray(gains)
        n = grid.count
        gain = np.empty(n, dtype=np.float32)
        emit = np.empty(n)
        ordered = gains_and_emission_times(
            grid.t, grid.u, grid.offsets, coeffs, gains, np.float32(self.amplitude),
            self.amplitude != 1.0, gain, emit,
        )  # fmt: skip
        if not ordered:  # the transmit is read at sorted times only
            out += self.render(grid)
            return
        win, a, b = transmit.hop_window(float(emit[0]), float(emit[-1]))
        phase = np.empty(n, dtype=np.float32)
        hop = np.empty(n, dtype=np.int64)
        transmit_phases(
            emit, win.snap_start_s, win.start_s, win.freq_hz, win.half_chirp, win.phase_cycles,
            win.chirped, a, b, phase, hop,
        )  # fmt: skip
        np.cos(phase, out=phase)
        add_echo(gain, phase, hop, win.amplitude, win.unit, out)

    def block(self, n0: int, count: int) -> FloatArray:
        """Received samples ``n0 … n0 + count − 1`` at ``fs_hz``, shape ``(count,)``."""
        sample_times(n0, count, self.fs_hz)  # checks n0 and count
        out = np.empty(int(count))
        for a in range(0, int(count), SUB_BLOCK):
            m = min(SUB_BLOCK, int(count) - a)
            out[a : a + m] = self.render(self.sample_grid(int(n0) + a, m))
        return out


def store_batches(echoes: Sequence[GridEcho], b: int, sols: Sequence[PathSolution]) -> None:
    """:meth:`GridEcho.store_batch` of ``b`` for each echo (all on one grid) from its
    solution at :meth:`GridEcho.batch_times`: the paths stacked, one array operation for all
    of them (the same values per path: every operation is elementwise)."""
    first = echoes[0]
    p = first.prefetch
    span = first.grid_samples / first.fs_hz  # s per unit u
    g_all = np.stack(
        [np.asarray(e.gain(sol), dtype=np.float64) for e, sol in zip(echoes, sols, strict=True)]
    )
    d_all = np.stack([sol.delay_s for sol in sols])
    s_all = (1.0 - np.stack([sol.alpha for sol in sols])) * span
    d0, dq1, dm, dq3, d1 = (d_all[:, q::4][:, :p] if q < 4 else d_all[:, 4::4] for q in range(5))
    s0, sm, s1 = s_all[:, 0:-1:4], s_all[:, 2::4], s_all[:, 4::4]
    c2 = 3.0 * (d1 - d0) - 2.0 * s0 - s1
    c3 = 2.0 * (d0 - d1) + s0 + s1

    def cubic(u: float) -> FloatArray:
        return d0 + u * (s0 + u * (c2 + u * c3))

    delay_err = np.maximum.reduce(
        [
            np.abs(cubic(0.25) - dq1),
            np.abs(cubic(0.5) - dm),
            np.abs(cubic(0.75) - dq3),
            np.abs(s0 + c2 + 0.75 * c3 - sm),  # slope at ½ (s per unit u)
        ]
    )
    tolerance = np.array([[e.tolerance_s] for e in echoes])
    limit = np.maximum(0.5 * tolerance, 16.0 * _EPS * np.abs(sols[0].t_rx_s[2::4]))
    g0, gq1, gm, gq3, g1 = (g_all[:, q::4][:, :p] if q < 4 else g_all[:, 4::4] for q in range(5))
    gb = 4.0 * gm - 3.0 * g0 - g1
    gc = 2.0 * (g0 + g1) - 4.0 * gm
    gain_err = np.maximum(
        np.abs(g0 + 0.25 * gb + 0.0625 * gc - gq1), np.abs(g0 + 0.75 * gb + 0.5625 * gc - gq3)
    )
    gain_tolerance = np.array([[e.gain_tolerance] for e in echoes])
    exact = (delay_err > limit) | (gain_err > gain_tolerance / 3.0 * np.abs(gm))
    gains = np.stack((g0, gb, gc), axis=1).astype(np.float32)  # 1e-7: below the transmit's
    coeffs = np.stack((d0, s0, c2, c3), axis=1)
    for i, e in enumerate(echoes):
        e._keep(b, _Batch(coeffs[i], gains[i], exact[i]))


def _still_path(path: PropagationPath) -> bool:
    """Whether every trajectory of ``path`` (its ``tx``, ``target``, ``rx``) is ``still``:
    the same position, bit for bit, at every time."""
    ends = [getattr(path, name) for name in ("tx", "target", "rx") if hasattr(path, name)]
    return bool(ends) and all(getattr(end, "still", False) for end in ends)


class SampleGrid:
    """Per-block arrays that every path on the same grid shares.

    Samples ``n0 … n0 + count − 1`` lie in intervals ``ka … kb`` (``k = n >> log2 h``);
    interval ``ka + i`` holds ``counts[i]`` of them, from offset ``offsets[i]``; ``u`` is each
    sample's position in its interval (``[0, 1)``), ``t`` its time (s).
    """

    def __init__(self, n0: int, count: int, h: int, fs_hz: float, t_start_s: float) -> None:
        self.t = sample_times(n0, count, fs_hz, t_start_s)
        self.n0, self.count, self.h = int(n0), int(count), int(h)
        self._u32: NDArray[np.float32] | None = None
        shift = h.bit_length() - 1
        if self.count == 0:
            self.ka, self.kb = 0, -1
            self.counts = self.offsets = np.zeros(1, dtype=np.int64)
            self.u = np.zeros(0)
            self.whole = False
            return
        self.ka, self.kb = self.n0 >> shift, (self.n0 + self.count - 1) >> shift
        edges = np.arange(self.ka, self.kb + 2, dtype=np.int64) * h
        edges[0], edges[-1] = self.n0, self.n0 + self.count
        self.offsets = edges - self.n0
        self.counts = np.diff(edges)
        n = np.arange(self.n0, self.n0 + self.count, dtype=np.int64)
        self.u = (n & (h - 1)).astype(np.float64)
        self.u *= 1.0 / h
        #: Whole intervals only: per-interval values broadcast over a (m, h) layout.
        self.whole = self.n0 % h == 0 and self.count % h == 0

    def polynomial(self, coeffs: NDArray[np.floating[Any]]) -> NDArray[np.floating[Any]]:
        """``Σ_i coeffs[i, k] u^i`` of every sample (Horner, highest power first), ``(count,)``,
        in the dtype of ``coeffs`` (float64 or float32).

        ``coeffs`` has one row per power and one column per interval ``ka … kb``. Every
        sample gets the same arithmetic in both layouts, so the values do not depend on the
        block.
        """
        top = coeffs.shape[0] - 1
        single = coeffs.dtype == np.float32
        if single and self._u32 is None:
            self._u32 = self.u.astype(np.float32)
        u = self._u32 if single and self._u32 is not None else self.u
        if self.whole:
            u_row = u[: self.h]
            out = coeffs[top][:, None] * u_row
            for i in range(top - 1, -1, -1):
                out += coeffs[i][:, None]
                if i:
                    out *= u_row
            return out.reshape(-1)
        out = np.repeat(coeffs[top], self.counts)
        out *= u
        for i in range(top - 1, -1, -1):
            out += np.repeat(coeffs[i], self.counts)
            if i:
                out *= u
        return out


class EchoBank:
    """Several :class:`GridEcho` paths on one grid, summed: the paths' batches are solved
    together by :func:`~sim_devices.acoustics.delay.solve_paths` and the per-block arrays are
    shared. ``block(n0, count)`` equals the sum of the echoes' own ``block`` bit for bit
    (added in the order given).
    """

    def __init__(self, echoes: Sequence[GridEcho]) -> None:
        self.echoes = list(echoes)
        if self.echoes:
            first = self.echoes[0]
            key = (first.fs_hz, first.t_start_s, first.grid_samples, first.prefetch)
            for e in self.echoes[1:]:
                if (e.fs_hz, e.t_start_s, e.grid_samples, e.prefetch) != key:
                    raise ConfigError(
                        "EchoBank echoes", "different grids",
                        "one fs_hz, t_start_s, grid_samples and prefetch_intervals",
                    )  # fmt: skip

    def _solve(self, grid: SampleGrid) -> None:
        first = self.echoes[0]
        p = first.prefetch
        for b in range(grid.ka // p, grid.kb // p + 1):
            todo = [e for e in self.echoes if not e.has_batch(b)]
            if todo:
                sols = solve_paths([e.path for e in todo], first.batch_times(b))
                store_batches(todo, b, sols)

    def block(self, n0: int, count: int) -> FloatArray:
        """Sum of the echoes' samples ``n0 … n0 + count − 1``, shape ``(count,)``."""
        sample_times(n0, count, 1.0)  # checks n0 and count
        out = np.zeros(int(count))
        if not self.echoes:
            return out
        first = self.echoes[0]
        for a in range(0, int(count), SUB_BLOCK):
            m = min(SUB_BLOCK, int(count) - a)
            grid = first.sample_grid(int(n0) + a, m)
            self._solve(grid)
            acc = out[a : a + m]
            for e in self.echoes:
                e.add_render(grid, acc)
        return out
