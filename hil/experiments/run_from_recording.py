"""A run's outcome rebuilt from its recording alone (``hil report RUN.h5``): what a run left
when it could not write its summary (``kill -9``, power loss), or a summary to write again.

What a recording holds is what the live run scored with: the experiment file, the estimates,
the stage telemetry (every report, with how long it took to come back: the late ones are left
out of the truth here as live), the SYNC pairs that map it onto sample time, the events (gaps,
xruns, how the run stopped); so the scoring keys of a rebuilt summary equal the live ones.
The GCAS receiver's time-codeword map is rebuilt by replaying the live receiver over the
samples (the same cells; the power of a few differs from live, as GCAS's map depends on where
its input was cut into calls, its estimates do not). Not recorded, so not in a rebuilt
summary: the host's wall time (its real-time factor is left out), the capture backlog and the
simulated tank's exact truth. Recordings made before the reply time was recorded use every
report. Xruns are counted from the recorded events.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from hil.errors import ConfigError
from hil.experiments.experiment import Experiment, parse_experiment
from hil.experiments.live.board_state import sample_index_at, stamped_in_callback
from hil.experiments.run_calibrations import RunCalibrations, load_run_calibrations
from hil.experiments.tank_run import CodewordMaps, RunOutcome, Telemetry
from hil.recording.reader import RunRecording
from hil.recording.replay import replay

#: The error of a rebuilt run whose recording has no stop event.
KILLED = (
    "the recording ends without a stop event: the run was killed before it could stop"
    " (kill -9, a crash or power loss); transmission and the stage were not stopped by it"
)


def outcome_from_recording(
    path: Path, folder: Path | None = None, *, codeword_map: bool = True
) -> RunOutcome:
    """The :class:`~hil.experiments.tank_run.RunOutcome` of the run recorded at ``path``, its
    folder ``folder`` (default: the recording's own), for
    :func:`~hil.experiments.run_scoring.summarize` and
    :func:`~hil.experiments.run_report.write_report` (see the module docstring for what a
    recording cannot give back). ``codeword_map``: replay a live GCAS receiver for its map
    (seconds of CPU per minute of recording)."""
    maps = CodewordMaps()
    with RunRecording.open(path) as rec:
        meta = rec.metadata
        if not meta.experiment_toml.strip():
            raise ConfigError(
                "recording",
                str(path),
                "a tank-run recording (it holds its experiment file)",
                "this recording was not written by hil tank-run; use hil replay for it",
            )
        exp = parse_experiment(meta.experiment_toml)
        c = float(rec.schedule_document()["sound_speed_mps"])
        exp = dataclasses.replace(
            exp, sound_speed_mps=c, waveform=dataclasses.replace(exp.waveform, sound_speed_mps=c)
        )
        segments = rec.segments()
        start = int(segments.sample_index[0]) if len(segments) else rec.origin_sample
        end = int(segments.stop_index[-1]) if len(segments) else start
        estimates = rec.estimates()
        events = [(e.kind, e.sample_index, e.length, e.text) for e in rec.events()]
        telemetry = _telemetry(rec, rec.fs_hz, exp.board_url)
        fs = rec.fs_hz
        origin = rec.origin_sample
        live = rec.metadata.receiver
        if live is not None and "background" in live.settings:
            # The capture the live receiver used (a file's "simulated" names the run's own).
            options = {**exp.receiver_options, "background": live.settings["background"]}
            exp = dataclasses.replace(exp, receiver_options=options)
        if codeword_map and live is not None and live.name in ("gcas", "gcas-mti", "gcas-bg"):
            replay(rec, hooks=maps.hooks(live.name))
    stops = [text for _, _, _, text in events if text.startswith("stop: ")]
    if stops:
        stop = stops[-1].removeprefix("stop: ")
        interrupted = stop.startswith("interrupted")
        error = "" if stop == "completed" else stop.removeprefix("error: ")
    else:
        interrupted, error = True, KILLED
        events.append(("alarm", end, 0, f"stop: {KILLED}"))
    return RunOutcome(
        folder=folder or Path(path).parent,
        experiment=exp,
        fs_hz=fs,
        start_index=start,
        samples=end - start,
        estimates=estimates,
        telemetry=telemetry,
        dropped_samples=sum(length for kind, _, length, _ in events if kind == "gap"),
        dac_underruns=sum(1 for kind, *_ in events if kind == "underrun"),
        adc_overruns=sum(1 for kind, *_ in events if kind == "overrun"),
        events=[e for e in events if not e[3].startswith("loopback latency")],
        wall_s=0.0,
        signal_s=(end - start) / fs,
        windows=[],
        interrupted=interrupted,
        error=error,
        latency_samples=origin - start,
        map_times=maps.times,
        map_power=maps.power,
        calibrations=_calibrations(exp, fs, meta.calibration_ids),
    )


def _telemetry(rec: RunRecording, fs: float, board_url: str) -> Telemetry:
    """The recorded stage telemetry, mapped onto sample time as the live run maps it after
    its end, through the sync pairs of the whole run as its DAC/ADC ``board_url`` stamps
    them (:func:`~hil.experiments.live.board_state.sample_index_at`)."""
    tel = rec.telemetry()
    pairs = rec.sync_pairs()
    host = np.array([t.host_time_s for t in tel], dtype=float)
    mapped = sample_index_at(
        host,
        list(zip(pairs.sample_index.tolist(), pairs.host_time_s.tolist(), strict=True)),
        fs,
        in_callback=stamped_in_callback(board_url),
    )
    index = np.round(mapped).astype(np.int64).tolist() if mapped is not None else [-1] * len(tel)
    return Telemetry(
        host_time_s=host.tolist(),
        sample_index=index,
        position_m=[t.position_m for t in tel],
        velocity_mps=[t.velocity_mps for t in tel],
        state=[t.state for t in tel],
        reply_s=[t.reply_s for t in tel],
    )


def _calibrations(exp: Experiment, fs: float, ids: tuple[str, ...]) -> RunCalibrations:
    """The run's calibrations from its store, when it still holds them (the stage's
    correction changes the truth); none when the run required none."""
    if not ids:
        return RunCalibrations()
    cals = load_run_calibrations(exp, fs)
    if cals.ids != ids:
        raise ConfigError(
            "calibration.store",
            str(exp.calibration_store),
            f"the store holding the run's calibrations {', '.join(ids)}",
            f"it now gives {', '.join(cals.ids) or 'none'}; run hil report from the folder the"
            " run was started in",
        )
    return cals
