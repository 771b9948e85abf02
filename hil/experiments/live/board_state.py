"""What the board (or audio interface) tells a run beyond its samples: its annotations as
recording events, whether it stopped on its own, its xrun counters, and the SYNC pairs that
put host times (the stage's reports) onto sample time."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from hil.acquisition import Annotation, AnnotationKind
from hil.acquisition.clock_fit import SampleClockFit
from hil.acquisition.device import StreamingDevice, XrunStatus
from hil.recording.records import RunEvent

# Board annotations as recording events: the recording's kinds are coarser (schema
# EVENT_KINDS); the event's text starts with the annotation's own kind.
EVENT_KIND: dict[AnnotationKind, str] = {
    AnnotationKind.GAP: "gap",
    AnnotationKind.SEQUENCE_GAP: "gap",
    AnnotationKind.OVERLAP: "note",
    AnnotationKind.FRAME_ERROR: "alarm",
    AnnotationKind.DAC_UNDERRUN: "underrun",
    AnnotationKind.ADC_OVERRUN: "overrun",
    AnnotationKind.WATCHDOG: "alarm",
    AnnotationKind.DISCONNECT: "alarm",
    AnnotationKind.RECONNECT: "note",
    AnnotationKind.ALARM: "alarm",
    AnnotationKind.PROTOCOL_ERROR: "alarm",
    AnnotationKind.START_RETRY: "note",
}


def run_event(annotation: Annotation) -> RunEvent:
    """A board annotation as a recording event (kind mapped by :data:`EVENT_KIND`, the text
    led by the annotation's own kind).

    >>> from hil.acquisition import Annotation
    >>> run_event(Annotation(120, AnnotationKind.SEQUENCE_GAP, 2, "seq 5 expected"))
    RunEvent(kind='gap', sample_index=120, length=2, text='sequence_gap: seq 5 expected')
    """
    return RunEvent(
        EVENT_KIND[annotation.kind],
        annotation.sample_index,
        annotation.length,
        f"{annotation.kind.value}: {annotation.detail}",
    )


def board_stopped(board: StreamingDevice) -> str | None:
    """Why the board stopped streaming on its own (its watchdog expired: the host sent it
    nothing for the watchdog timeout), as an error message; None while it streams. A run
    stops at once on it: no more samples will come.

    Works for the board and the audio interface (both keep ``annotations``).
    """
    stops = board.annotations.of_kind(AnnotationKind.WATCHDOG)
    if not stops:
        return None
    at = stops[0]
    return (
        f"the board stopped streaming at sample {at.sample_index} ({at.detail}): the host"
        " sent it nothing for its watchdog timeout, so the host stalled (a loaded machine, a"
        " slow disk); the recording holds everything before it"
    )


def xrun_counts(status: XrunStatus | None) -> tuple[int, int]:
    """``(dac_underruns, adc_overruns)`` in a device's status; ``(0, 0)`` before any status.

    >>> from hil.devices.audio.daq import AudioDaqStatus
    >>> xrun_counts(AudioDaqStatus(frames=4096, overruns=2, underruns=1))
    (1, 2)
    """
    if status is None:
        return 0, 0
    return int(status.dac_underruns), int(status.adc_overruns)


def xruns_since(before: tuple[int, int], status: XrunStatus | None) -> tuple[int, int]:
    """``(dac_underruns, adc_overruns)`` since the counts ``before`` (from
    :func:`xrun_counts`), in ``status``. A counter lower than before has restarted (the
    board was power-cycled and the driver reconnected): its count is then the new value."""
    (dac, adc), (dac0, adc0) = xrun_counts(status), before
    return (dac - dac0 if dac >= dac0 else dac), (adc - adc0 if adc >= adc0 else adc)


def sample_zero_time_s(pairs: list[tuple[int, float]], fs: float) -> float | None:
    """Host time (s) of board sample 0, from SYNC pairs ``(sample_index, host_time_s)`` by
    minimum-delay filtering; None without pairs.

    A SYNC is stamped when the host reads it, which during streaming is after the ADC
    frames queued before it, so every pair is late by a varying backlog: with the known
    sample rate ``fs`` (Hz), the least-delayed pair gives the offset. The backlog is a few
    ms on a quiet machine but seconds after a stall of the host or the board, and then most
    pairs can be that late: only the least-delayed pair counts, however few are near it.
    No pair is early: the board's clock fit starts afresh when CONFIGURE is acknowledged and
    the link delivers in order, so a SYNC from an earlier configuration never reaches it.

    >>> pairs = [(1000, 11.003), (2000, 12.0015), (3000, 13.004)]  # delays 3, 1.5, 4 ms
    >>> late = [(4000 + k, 17.0 + k / 1000) for k in range(0, 5000, 500)]  # 3 s late
    >>> round(sample_zero_time_s(pairs + late, 1000.0), 6)
    10.0015
    """
    if not pairs:
        return None
    return float(min(host_t - index / fs for index, host_t in pairs))


def stamped_in_callback(board_url: str) -> bool:
    """Whether the DAC/ADC at ``board_url`` stamps its sync pairs in its own sample callback
    (an audio interface: ``audio://``, ``sim://audio``) rather than when its SYNC reaches
    the host (a board, whose SYNCs queue behind its ADC data).

    >>> stamped_in_callback("audio://JACK?rate=192000"), stamped_in_callback("sim://board")
    (True, False)
    """
    from hil.devices.audio.daq import is_audio_url

    return is_audio_url(board_url)


def sample_index_at(
    host_time_s: npt.ArrayLike,
    pairs: list[tuple[int, float]],
    fs: float,
    *,
    in_callback: bool,
) -> npt.NDArray[np.float64] | None:
    """Sample index (float) at each host time ``host_time_s`` (s, shape ``(n,)``) from the run's
    sync pairs ``(sample_index, host_time_s)``; None without pairs.

    A board's pairs (``in_callback=False``) are late by the ADC data queued before each
    SYNC: the least-delayed pair gives the offset and the nominal rate ``fs`` (Hz) the
    slope (:func:`sample_zero_time_s`). An audio interface's pairs (``in_callback=True``)
    are stamped in its callback, never behind a queue, so they follow the stream's own
    pace: the host times are interpolated between them, and beyond the first or last pair
    the nominal rate continues. A stream whose pace is not the nominal rate (a JACK server
    that waits for a late client, ``hil sim-serve tank --jack``) is then still mapped to
    the sample it was at, not to where a steady clock would have been.

    >>> pairs = [(0, 10.0), (1000, 12.0), (2000, 12.5)]  # the stream paused, then ran on
    >>> sample_index_at([11.0, 12.25, 13.0], pairs, 1000.0, in_callback=True).tolist()
    [500.0, 1500.0, 2500.0]
    >>> sample_index_at([11.0], pairs, 1000.0, in_callback=False).tolist()  # sample 0 at 10 s
    [1000.0]
    """
    if not pairs:
        return None
    host = np.atleast_1d(np.asarray(host_time_s, dtype=np.float64))
    if not in_callback:
        zero = sample_zero_time_s(pairs, fs)
        assert zero is not None
        return (host - zero) * fs
    ordered = sorted(pairs)
    index = np.array([p[0] for p in ordered], dtype=np.float64)
    # A stamp never goes back in time; one that does (a clock step) is held at the last.
    stamps = np.maximum.accumulate(np.array([p[1] for p in ordered], dtype=np.float64))
    out = np.interp(host, stamps, index)
    before, after = host < stamps[0], host > stamps[-1]
    out[before] = index[0] + (host[before] - stamps[0]) * fs
    out[after] = index[-1] + (host[after] - stamps[-1]) * fs
    return out


def collect_sync_pairs(fit: SampleClockFit | None, run_pairs: list[tuple[int, float]]) -> None:
    """Append to ``run_pairs`` the SYNC pairs ``(sample_index, host_time_s)`` of a device's
    clock fit (None: no device, or not configured) that it does not hold yet. The fit keeps
    only its latest pairs (a sliding window), so the run keeps its own list: every pair is
    recorded, and the least-delayed one of the whole run is never forgotten."""
    pairs = fit.pair_list() if fit is not None else []
    last = run_pairs[-1][0] if run_pairs else None
    run_pairs.extend(p for p in pairs if last is None or p[0] > last)
