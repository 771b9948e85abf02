"""The loopback latency of a run, measured on its first captured samples: the DAC monitor
input (ADC input 2, channel 1) against the transmitted schedule.

The receiver's sample 0 is the first sample that can hold the echo of transmit sample 0:
the board index where transmission started plus this latency. :class:`LatencyProbe` gathers
the first :data:`PROBE_S` of capture and measures it; with no loopback cabled, a required
latency calibration gives it instead.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hil.experiments.run_calibrations import RunCalibrations
from hil.signals.schedule import HopSchedule
from hil.signals.synthesis import BlockSynthesizer

#: Capture used to measure the loopback latency at the start of every run, s: delays up to
#: three quarters of it are measured (75 ms: an audio interface at 192 kHz buffers two blocks,
#: so blocks of up to 7000 frames).
PROBE_S = 0.1
#: Longest the probe gathers while the DAC monitor input is digital silence (exact zeros), s:
#: an analog input always holds some noise, so exact zeros are a digital path not yet carrying
#: the drive (a JACK graph whose ports are connected after the stream started, on a loaded
#: machine more than :data:`PROBE_S` later). Past it, the run says there is no loopback.
PROBE_MAX_S = 1.0


def measure_latency(monitor: np.ndarray, sent: np.ndarray, max_lag: int | None = None) -> int:
    """Integer-sample delay of ``monitor`` (the DAC drive as captured) behind ``sent``.

    >>> x = np.random.default_rng(0).normal(size=2000)
    >>> measure_latency(np.concatenate([np.zeros(37), x])[:2000], x)
    37
    """
    return measure_loopback(monitor, sent, max_lag)[0]


#: Least normalised correlation between the DAC monitor input and the transmitted samples
#: that counts as a loopback (a cabled monitor gives about 1; an open input about 0).
LOOPBACK_MIN_CORRELATION = 0.5


def measure_loopback(
    monitor: np.ndarray, sent: np.ndarray, max_lag: int | None = None
) -> tuple[int, float]:
    """``(delay, correlation)``: the integer-sample delay (0 .. ``max_lag``, default
    ``n - n // 4``, so that at least a quarter of the capture overlaps) of ``monitor``
    behind ``sent`` (both shape ``(n,)``) and the normalised correlation at that delay (1
    for a scaled, delayed copy; about 0 when the monitor does not carry ``sent``). The delay
    is where the correlation normalised by the overlap's energy peaks.

    >>> x = np.random.default_rng(0).normal(size=2000)
    >>> lag, rho = measure_loopback(0.1 * np.concatenate([np.zeros(37), x])[:2000], x)
    >>> lag, round(rho, 3)
    (37, 1.0)
    >>> measure_loopback(np.zeros(2000), x)
    (0, 0.0)
    """
    n = min(monitor.shape[0], sent.shape[0])
    lags = min(n - max(1, n // 4) if max_lag is None else max_lag, n - 1)
    nfft = 1 << (2 * n - 1).bit_length()
    m, s = np.asarray(monitor[:n], dtype=float), np.asarray(sent[:n], dtype=float)
    spectrum = np.fft.rfft(m, nfft) * np.conj(np.fft.rfft(s, nfft))
    # The envelope of the cross-correlation (its analytic signal: positive frequencies
    # doubled): a few tones a couple of kHz apart give a correlation whose carrier peaks
    # repeat every few hundred µs, and a delay between two samples can put a neighbouring
    # carrier peak above the true one. The envelope peaks at the delay.
    analytic = np.zeros(nfft, dtype=complex)
    analytic[: spectrum.size] = spectrum
    analytic[1 : spectrum.size - 1] *= 2.0
    envelope = np.abs(np.fft.ifft(analytic))[: lags + 1]
    # Normalised by the energy of the overlap at each delay (monitor[lag:] against
    # sent[:n - lag]): the raw correlation shrinks with the overlap, so a long true delay
    # would lose to a shorter one where the schedule resembles itself.
    m_tail = np.cumsum((m**2)[::-1])[::-1][: lags + 1]
    s_head = np.cumsum(s**2)[n - 1 - np.arange(lags + 1)]
    energy = m_tail * s_head
    rho = np.divide(envelope, np.sqrt(energy), out=np.zeros(lags + 1), where=energy > 0)
    lag = int(np.argmax(rho))
    return lag, float(rho[lag])


def loopback_latency(lat: int, rho: float, cals: RunCalibrations) -> tuple[int, str]:
    """The receiver's latency (samples) and the recording's note about it: measured on the
    DAC monitor input when it carries the loopback, else the required latency calibration's,
    else the run cannot place its sample 0 (RuntimeError: the run stops and says why)."""
    calibrated = cals.latency_samples
    if rho >= LOOPBACK_MIN_CORRELATION:
        note = f"loopback latency {lat} samples"
        if calibrated is not None and calibrated != lat:
            note += f" (calibration {cals.id_of('latency')} says {calibrated})"
        return lat, note
    if calibrated is None:
        raise RuntimeError(
            f"no loopback on the DAC monitor input (ADC input 2, channel 1): normalised"
            f" correlation {rho:.2f} < {LOOPBACK_MIN_CORRELATION}, so the loopback latency"
            " cannot be measured. Connect the transmit drive to ADC input 2 (on an audio"
            " interface: output 2, which plays the same signal; on the board: a tap on its"
            " DAC output; hil docs tank-run), or require a latency calibration:"
            ' calibration.required = ["latency"]'
        )
    return calibrated, (
        f"loopback latency {calibrated} samples from calibration {cals.id_of('latency')}"
        f" (the DAC monitor input carried no loopback: correlation {rho:.2f})"
    )


class LatencyProbe:
    """Gathers the first :data:`PROBE_S` of capture (blocks by board index) and measures the
    loopback latency on it against the schedule as transmitted from ``start_index``.

    ``scale`` converts the monitor channel's codes to full scale.
    """

    def __init__(
        self,
        schedule: HopSchedule,
        fs_hz: float,
        amplitude: float,
        start_index: int,
        scale: float,
        cals: RunCalibrations,
    ) -> None:
        self._schedule, self._fs, self._amplitude = schedule, fs_hz, amplitude
        self.start_index = start_index
        self._scale = scale
        self._cals = cals
        #: The blocks gathered, ``(first_index, data)``: the run records and feeds them once
        #: the latency (so the recording's origin) is known.
        self.blocks: list[tuple[int, np.ndarray[Any, Any]]] = []
        #: Capture sample (from the first block) of the block in which the DAC monitor input
        #: first held a non-zero sample; None while it has been digital silence.
        self._heard_from: int | None = None

    def add(self, first_index: int, data: np.ndarray[Any, Any]) -> bool:
        """Keep a block; True once enough capture is gathered to measure: :data:`PROBE_S`,
        or up to :data:`PROBE_MAX_S` while the DAC monitor input has been exact zeros."""
        gathered = sum(b.shape[0] for _, b in self.blocks)
        self.blocks.append((first_index, data))
        if self._heard_from is None and np.any(data[:, 1]):
            self._heard_from = gathered
        gathered += data.shape[0]
        if self._heard_from is None:
            return gathered >= PROBE_MAX_S * self._fs
        probe = PROBE_S * self._fs
        # Heard within a probe's length: the silence ahead may be the latency itself.
        return gathered - (self._heard_from if self._heard_from >= probe else 0) >= probe

    def measure(self) -> tuple[int, str]:
        """``(latency_samples, note)``: see :func:`loopback_latency`."""
        captured = np.concatenate([b for _, b in self.blocks])
        # Its own synthesizer: the one transmitting renders on the board's writer thread (or
        # the audio callback) and is not re-entrant.
        reference = BlockSynthesizer(self._schedule, self._fs, amplitude=self._amplitude)
        monitor = captured[:, 1] * self._scale
        n = captured.shape[0]
        probe = int(PROBE_S * self._fs)
        k0 = int(np.argmax(monitor != 0.0)) if monitor.any() else 0
        if k0 >= probe:
            # Silent for a whole probe: a digital path that began carrying the drive at k0.
            # The drive heard from there was sent up to ``limit`` earlier, so the reference
            # from k0 - limit leads it by limit - latency.
            limit = probe - probe // 4
            heard = monitor[k0:]
            lead, rho = measure_loopback(reference.render(k0 - limit, heard.size), heard, limit)
            lat = limit - lead
        else:
            limit = n - n // 4
            lat, rho = measure_loopback(monitor, reference.render(0, n), limit)
        if rho >= LOOPBACK_MIN_CORRELATION and lat >= limit:
            # The peak at the end of the search: the true delay may lie beyond it.
            raise RuntimeError(
                f"loopback latency of {lat} samples or more: beyond the {limit} samples"
                f" ({limit / self._fs:g} s) the run's latency probe measures; lower the audio"
                " interface's blocksize or latency setting"
            )
        return loopback_latency(lat, rho, self._cals)
