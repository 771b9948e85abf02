"""``hil simulate``: run a scenario file through the simulated acoustic channel.

Example::

    hil simulate att --out runs/att/          # a shipped example scenario
    hil simulate my-tank.toml                 # into runs/simulate-my-tank-YYYYmmdd-HHMMSS/

Writes into ``--out``: ``received.wav`` (float32, one channel per ``[output].channels``
entry), ``schedule.json`` (the transmit schedule, ``hil.signals.schedule_file`` format),
``truth.csv`` and ``truth.json`` (every hop boundary on every target's echo) and, unless
``[output].plots = false``, ``spectrogram.png`` and ``truth.png``. The scenario format is in
``docs/scenarios.md``. ``sim_devices`` is imported inside :func:`run` only.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import re
import sys
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from hil.errors import ConfigError


def register(sub: Any) -> None:
    """Add the ``simulate`` sub-command."""
    p: argparse.ArgumentParser = sub.add_parser(
        "simulate",
        help="simulate the received signal of a scenario (WAV + schedule + truth + plots)",
        description="Run a scenario TOML file (format: hil docs scenarios) through the "
        "simulated acoustic channel and write the received WAV, the transmit schedule, the "
        "hop-by-hop truth and plots into --out.",
    )
    p.add_argument(
        "scenario",
        help="scenario TOML file, or the name of a shipped example "
        "(att, tank-audio, tank-board; see hil docs scenarios)",
    )
    p.add_argument(
        "--out",
        type=Path,
        metavar="DIR",
        help="output folder, new or empty (an earlier simulation is never overwritten); "
        "default: a new folder simulate-NAME-YYYYmmdd-HHMMSS in the runs folder "
        "($HIL_RUNS_DIR, else ./runs)",
    )
    p.add_argument(
        "--duration", type=float, help="override duration_s, s (default: the scenario's)"
    )
    p.add_argument(
        "--quiet",
        action="store_true",
        help="no progress on stderr (on a terminal a redrawn percentage, else a line per 10 %%)",
    )
    p.set_defaults(func=run)


def _scenario_file(text: str) -> Path:
    """The scenario file ``text`` names: a path, else a shipped example's name."""
    path = Path(text)
    if path.exists() or path.suffix == ".toml":
        return path
    from hil.data import scenario_path

    return scenario_path(text)


def run(args: argparse.Namespace) -> int:
    """Execute ``hil simulate``; return the exit status."""
    from hil.outputs import claim_output_folder, release_output_folder
    from sim_devices.acoustics.scenario import load_scenario

    sc = load_scenario(_scenario_file(args.scenario))
    if args.duration is not None:
        if not (np.isfinite(args.duration) and args.duration > 0):
            raise ConfigError("--duration", args.duration, "> 0 s")
        sc.duration_s = float(args.duration)
    _check_wav_size(sc, "--duration" if args.duration is not None else "duration_s")
    if args.out is None:
        args.out = new_simulation_folder(args.scenario, dt.datetime.now())
    _check_free_space(sc, args.out)
    claim_output_folder(args.out, "--out", holds="a simulation")
    try:
        return _write_simulation(args, sc)
    except KeyboardInterrupt:
        # Said before the interruption's own line (hil.cli.main): what the folder holds.
        written = sorted(p.name for p in args.out.iterdir() if not p.name.startswith("."))
        print(
            f"hil simulate: {args.out} holds a partial simulation, cut short at the"
            f" interruption ({', '.join(written) or 'no files'}): simulate again into a new"
            " folder",
            file=sys.stderr,
        )
        raise
    finally:
        release_output_folder(args.out)


#: The largest received.wav: a RIFF WAV counts its bytes in 32 bits.
_WAV_MAX_BYTES = 2**32 - 1 - 64


def _check_wav_size(sc: Any, field: str) -> None:
    """Refuse a scenario whose received.wav (float32, every output channel) would pass the
    RIFF limit of 4 GiB; ``field`` names the duration as the user gave it."""
    per_second = 4 * len(sc.output_channels) * sc.fs_hz
    longest = _WAV_MAX_BYTES / per_second
    if not sc.duration_s <= longest:
        raise ConfigError(
            field,
            sc.duration_s,
            f"<= {longest:.6g} s (received.wav of {len(sc.output_channels)} float32 channels"
            f" at {sc.fs_hz:g} Hz stays within a WAV's 4 GiB)",
            "simulate a shorter run, or fewer output channels (output.channels)",
        )


def _check_free_space(sc: Any, out: Path) -> None:
    """Refuse a simulation whose received.wav (float32, every output channel) would not fit
    the room where ``out`` goes (:func:`~hil.experiments.live.disk_room.room_left`: its disk's
    free space, or the file-size limit ``ulimit -f``), read at its nearest existing folder."""
    from hil.experiments.live.disk_room import room_left

    size = 4 * len(sc.output_channels) * sc.fs_hz * sc.duration_s
    where = Path(out).resolve()
    while not where.exists() and where != where.parent:
        where = where.parent
    if os.statvfs(where).f_blocks == 0:
        return  # not a disk (/proc, /sys): the folder's claim says it cannot be written
    room, bound = room_left(where / "received.wav")
    if size > room:
        raise ConfigError(
            "--out",
            str(out),
            f"a folder with room for received.wav ({size / 1e9:.3g} GB; {room / 1e9:.3g} GB"
            f" left there: {bound})",
            "free some space (or raise the limit), write --out elsewhere, or simulate a"
            " shorter run",
        )


def new_simulation_folder(scenario: str, now: dt.datetime) -> Path:
    """A new, empty folder ``simulate-NAME-YYYYmmdd-HHMMSS`` (``-2``, ``-3``, ... when one of
    that second exists) in the runs folder (:func:`hil.paths.resolve_runs_dir`); ``NAME`` is
    the scenario file's stem, or the shipped example's name."""
    from hil.outputs import writable_folder
    from hil.paths import RUNS_ENV, resolve_runs_dir

    runs = writable_folder(resolve_runs_dir(), f"the runs folder (${RUNS_ENV}, else ./runs)")
    name = re.sub(r"[^A-Za-z0-9_.-]+", "_", Path(scenario).stem) or "scenario"
    stem = f"simulate-{name}-{now:%Y%m%d-%H%M%S}"
    for k in range(1, 1000):
        folder = runs / (stem if k == 1 else f"{stem}-{k}")
        try:
            folder.mkdir()
        except FileExistsError:
            continue
        return folder
    raise ConfigError(
        "--out", None, "given: 1000 simulations of this scenario started this second", "name one"
    )


class PercentProgress:
    """Progress of a simulation on ``stream``: on a terminal one percentage redrawn in place
    (``\r``), else (a log file, a pipe) one line per 10 % step, so a log holds no control
    characters and a few lines, not thousands.

    >>> import io
    >>> out = io.StringIO()
    >>> p = PercentProgress(out, tty=False)
    >>> for done in (5, 10, 55, 100):
    ...     p.update(done, 100)
    >>> p.close()
    >>> print(out.getvalue(), end="")
    simulate:  10 %
    simulate:  50 %
    simulate: 100 %
    """

    def __init__(self, stream: TextIO, tty: bool | None = None) -> None:
        self.stream = stream
        self.tty = stream.isatty() if tty is None else tty
        self._step = 0  # the last 10 % step printed

    def update(self, done: int, total: int) -> None:
        """``done`` of ``total`` samples written."""
        percent = 100.0 * done / total
        if self.tty:
            self.stream.write(f"\rsimulate: {percent:5.1f} %")
            self.stream.flush()
            return
        step = int(percent // 10)
        if step > self._step:
            self._step = step
            self.stream.write(f"simulate: {10 * step:3d} %\n")
            self.stream.flush()

    def close(self) -> None:
        """End the redrawn line (on a terminal)."""
        if self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _write_simulation(args: argparse.Namespace, sc: Any) -> int:
    """The scenario ``sc`` simulated into the claimed ``--out``: WAV, schedule, truth,
    plots; the summary line printed."""
    from hil.signals.schedule_file import schedule_document, write_schedule_file
    from sim_devices.acoustics.scenario import build_channel
    from sim_devices.acoustics.truth import hop_truth, write_truth

    channel = build_channel(sc)
    n_total = int(round(sc.duration_s * sc.fs_hz))
    block = max(1, int(round(sc.block_s * sc.fs_hz)))
    wav_path = args.out / "received.wav"
    keep_for_plot = min(n_total, int(sc.fs_hz * 2.0))
    first = np.zeros(0)
    progress = None if args.quiet else PercentProgress(sys.stderr)
    with _FloatWav(wav_path, int(round(sc.fs_hz)), len(sc.output_channels), n_total) as wav:
        done = 0
        while done < n_total:
            count = min(block, n_total - done)
            parts = channel.read_components(count)
            frame = np.stack([parts[name] if name == "received" else
                              parts[name] * (channel.receiver.volts_per_upa / channel.receiver.full_scale_v)  # noqa: E501
                              for name in sc.output_channels], axis=1)  # fmt: skip
            wav.write(frame.astype(np.float32))
            if first.size < keep_for_plot:
                first = np.concatenate([first, parts["received"][: keep_for_plot - first.size]])
            done += count
            if progress is not None:
                progress.update(done, n_total)
    if progress is not None:
        progress.close()
    if channel.clipped_samples:
        # Never silent: the ADC clipped (received.wav holds the clipped samples).
        print(
            f"simulate: warning: {channel.clipped_samples} received samples clipped at full"
            " scale; lower sonar.source_level_db or sonar.gain_db",
            file=sys.stderr,
        )
    doc = schedule_document(sc.schedule, sc.fs_hz, sc.duration_s,
                            sound_speed_mps=sc.sound_speed_mps, spec=sc.spec.to_dict())  # fmt: skip
    write_schedule_file(args.out / "schedule.json", doc)
    rows = []
    for i, tgt in enumerate(sc.targets):
        rows += hop_truth(sc.schedule, sc.sonar, tgt.trajectory, sc.sound_speed_mps,
                          sc.duration_s, sc.max_delay_s, i)  # fmt: skip
    write_truth(rows, args.out / "truth.csv", args.out / "truth.json")
    written = ["received.wav", "schedule.json", "truth.csv", "truth.json"]
    if sc.plots:
        written += _plots(args.out, first, sc.fs_hz, rows)
    print(json.dumps({"out": str(args.out), "samples": n_total, "fs": sc.fs_hz,
                      "channels": list(sc.output_channels), "hop_boundaries": len(rows),
                      "clipped_samples": channel.clipped_samples,
                      "files": written}))  # fmt: skip
    return 0


class _FloatWav:
    """Streaming IEEE-float WAV writer: header first, frames appended, bounded memory."""

    def __init__(self, path: Path, fs: int, channels: int, frames: int) -> None:
        self.path, self.fs, self.channels, self.frames = path, fs, channels, frames

    def __enter__(self) -> _FloatWav:
        import struct

        data = 4 * self.channels * self.frames
        header = b"RIFF" + struct.pack("<I", 4 + 26 + 12 + 8 + data) + b"WAVE"
        header += b"fmt " + struct.pack("<IHHIIHHH", 18, 3, self.channels, self.fs,
                                        self.fs * 4 * self.channels, 4 * self.channels, 32, 0)  # fmt: skip  # noqa: E501
        header += b"fact" + struct.pack("<II", 4, self.frames)
        header += b"data" + struct.pack("<I", data)
        self.fh = self.path.open("wb")
        self.fh.write(header)
        return self

    def write(self, frame: np.ndarray) -> None:
        self.fh.write(np.ascontiguousarray(frame, dtype="<f4").tobytes())

    def __exit__(self, *exc: object) -> None:
        self.fh.close()


def _plots(out: Path, x: np.ndarray, fs: float, rows: list[Any]) -> list[str]:
    from hil.figures import new_figure

    fig, ax = new_figure(figsize=(8, 4))
    nfft = 1024 if x.size >= 1024 else max(16, x.size)
    ax.specgram(x + 1e-12, NFFT=nfft, Fs=fs, noverlap=nfft // 2, cmap="viridis")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("frequency (Hz)")
    ax.set_title("received signal")
    fig.savefig(out / "spectrogram.png", dpi=90)
    fig, (a1, a2) = new_figure(2, 1, sharex=True, figsize=(8, 5))
    for tgt in sorted({r.target for r in rows}):
        sel = [r for r in rows if r.target == tgt]
        a1.plot([r.t_rx_s for r in sel], [r.range_m for r in sel], ".", label=f"target {tgt}")
        a2.plot([r.t_rx_s for r in sel], [r.radial_speed_mps for r in sel], ".")
    a1.set_ylabel("range at bounce (m)")
    a2.set_ylabel("closing speed (m/s)")
    a2.set_xlabel("receive time of hop boundary (s)")
    if rows:
        a1.legend()
    fig.savefig(out / "truth.png", dpi=90)
    return ["spectrogram.png", "truth.png"]
