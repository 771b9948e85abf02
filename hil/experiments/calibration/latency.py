"""Loopback latency: the sample-exact delay from DAC out to ADC in, measured N times.

Each repeat is one separate play/record run (a real interface may pick a different buffer
alignment every time a stream opens): one block of silence, the reference LFM chirp
(:func:`~hil.devices.audio.latency.reference_chirp`), then silence long enough to hear it
back. The integer lag of the matched-filter peak is the latency of that run. A run whose
correlation peak is weak (peak-to-sidelobe ratio or loop gain below the limits) is refused:
the loop is open, unplugged, muted or drowned in noise.

Applied as: input sample ``n + latency`` holds what came back of output sample ``n``
(:func:`hil.experiments.calibration.apply.align_recording`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hil.devices.audio.latency import matched_filter_delay, reference_chirp
from hil.experiments.calibration.device import (
    CalibrationError,
    PlayRecordDevice,
    check_channel,
    check_positive_int,
)

KIND = "latency"


@dataclass(frozen=True)
class LatencyResult:
    """Loopback latency over ``len(samples)`` runs.

    Attributes
    ----------
    samples:
        Latency of every run, integer samples.
    samplerate:
        Hz.
    latency_samples:
        The value applied: the median run (an integer: the lower median for an even count).
    mean_samples, std_samples, spread_samples:
        Mean, standard deviation and max - min of the runs, samples.
    min_peak_to_sidelobe_db:
        Worst peak-to-sidelobe ratio of the matched filter over the runs, dB.
    loop_gain:
        Median matched-filter loop gain (received / sent amplitude; 1 for a digital cable).
    output_channel, input_channel:
        The channels measured.
    """

    samples: tuple[int, ...]
    samplerate: float
    latency_samples: int
    mean_samples: float
    std_samples: float
    spread_samples: int
    min_peak_to_sidelobe_db: float
    loop_gain: float
    output_channel: int = 0
    input_channel: int = 0

    @property
    def latency_s(self) -> float:
        """The applied latency in seconds."""
        return self.latency_samples / self.samplerate

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict (see :meth:`from_json`)."""
        d = dict(self.__dict__)
        d["samples"] = list(self.samples)
        return d

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> LatencyResult:
        """Inverse of :meth:`to_json`."""
        return cls(**{**d, "samples": tuple(int(s) for s in d["samples"])})

    def summary(self) -> list[str]:
        """Human-readable lines for the command line."""
        values = ", ".join(str(s) for s in self.samples)
        return [
            f"latency: {self.latency_samples} samples = {1e3 * self.latency_s:.4f} ms "
            f"at {self.samplerate:g} Hz (output {self.output_channel} -> input "
            f"{self.input_channel})",
            f"runs: {len(self.samples)}: [{values}]; mean {self.mean_samples:.3f}, "
            f"std {self.std_samples:.3f}, spread {self.spread_samples} samples",
            f"quality: worst peak-to-sidelobe {self.min_peak_to_sidelobe_db:.1f} dB, "
            f"loop gain {self.loop_gain:.4g}",
        ]


def calibrate_latency(
    device: PlayRecordDevice,
    *,
    repeats: int = 5,
    max_latency_frames: int | None = None,
    output_channel: int = 0,
    input_channel: int = 0,
    min_peak_to_sidelobe_db: float = 20.0,
    min_loop_gain: float = 1e-3,
) -> LatencyResult:
    """Measure the loopback latency ``repeats`` times (one play/record run each).

    Parameters
    ----------
    device:
        The play/record device; output ``output_channel`` must reach input ``input_channel``
        (a cable, or the transducer pair through the water).
    repeats:
        Number of runs, >= 1.
    max_latency_frames:
        Longest latency searched, samples; default 0.1 s.
    min_peak_to_sidelobe_db, min_loop_gain:
        Refuse a run whose correlation peak is weaker (:class:`CalibrationError`).

    Examples
    --------
    >>> from hil.devices.audio import AudioSettings, DigitalLoopbackWorld, SimulatedDuplex
    >>> from hil.experiments.calibration.device import from_duplex
    >>> sim = SimulatedDuplex(AudioSettings(48000, blocksize=64), DigitalLoopbackWorld(9))
    >>> r = calibrate_latency(from_duplex(sim), repeats=3)
    >>> r.samples, r.latency_samples   # 2 blocks of I/O delay + 9 samples of cable
    ((137, 137, 137), 137)
    """
    check_positive_int("repeats", repeats)
    check_channel("output_channel", output_channel, device.channels_out)
    check_channel("input_channel", input_channel, device.channels_in)
    fs = device.samplerate
    max_lat = round(0.1 * fs) if max_latency_frames is None else max_latency_frames
    check_positive_int("max_latency_frames", max_lat, 0)
    ref = reference_chirp(fs)
    lead = 64
    out = np.zeros((lead + ref.size, device.channels_out), dtype=np.float32)
    out[lead:, output_channel] = ref
    lags, psl, gains = [], [], []
    for run in range(repeats):
        rec = device.run(out, tail_frames=max_lat)
        window = rec[lead : lead + ref.size + max_lat, input_channel]
        m = matched_filter_delay(window, ref, fs)
        _check_run(run, m.peak_to_sidelobe_db, m.gain, m.samples, input_channel, max_lat,
                   min_peak_to_sidelobe_db, min_loop_gain)  # fmt: skip
        lags.append(m.samples)
        psl.append(m.peak_to_sidelobe_db)
        gains.append(m.gain)
    arr = np.asarray(lags)
    return LatencyResult(
        samples=tuple(int(v) for v in lags),
        samplerate=float(fs),
        latency_samples=int(np.sort(arr)[(arr.size - 1) // 2]),
        mean_samples=float(arr.mean()),
        std_samples=float(arr.std()),
        spread_samples=int(arr.max() - arr.min()),
        min_peak_to_sidelobe_db=float(min(psl)),
        loop_gain=float(np.median(gains)),
        output_channel=output_channel,
        input_channel=input_channel,
    )


def _check_run(
    run: int,
    psl_db: float,
    gain: float,
    lag: int,
    channel: int,
    max_lat: int,
    min_psl_db: float,
    min_gain: float,
) -> None:
    """Refuse a run whose chirp was not found cleanly, saying what to check."""
    if not (psl_db >= min_psl_db and abs(gain) >= min_gain):
        psl_text = "no signal" if psl_db == -math.inf else f"{psl_db:.1f} dB"
        raise CalibrationError(
            f"latency run {run + 1}: the reference chirp did not come back on input "
            f"{channel} (peak-to-sidelobe {psl_text}, need >= {min_psl_db:g} dB; loop gain "
            f"{gain:.3g}, need >= {min_gain:g}; best lag {lag} samples): the loop looks open. "
            f"Connect the output to the input (or check levels, mute and wiring), or raise "
            f"--max-latency if the latency exceeds {max_lat} samples"
        )
