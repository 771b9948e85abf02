"""The exact truth of a tank simulated in another process (hil.experiments.exact_truth): the
table, its file, the JACK tank writing one per run on the run's time base, and ``hil report
--exact-truth`` reading it (the whole path through JACK: test_tank_run_jack.py)."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.devices.audio.contract import BlockTime, StatusFlags
from hil.errors import ConfigError
from hil.experiments.exact_truth import (
    COLUMNS,
    STEP_S,
    read_truth,
    truth_at,
    truth_table,
    write_truth,
)
from hil.experiments.experiment import DEFAULT_EXPERIMENT, Experiment, parse_experiment
from hil.experiments.jack_tank import END_SILENT_BLOCKS, TankJackClient
from hil.experiments.tank_run import RunOutcome

EXP = parse_experiment(DEFAULT_EXPERIMENT)
#: An experiment whose transducer sits off the stage's line, so the line of sight turns as
#: the carriage passes: the closing speed is the velocity's projection, not the velocity.
OFF_AXIS = parse_experiment(
    DEFAULT_EXPERIMENT.replace(
        "transducer_position_m = [0.5, 2.0, -1.2]", "transducer_position_m = [0.5, 1.2, -0.8]"
    )
)


def _ramp(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A carriage at rest for 0.2 s, then 1 m/s² up to 1.5 m/s, then steady (m, m/s)."""
    t = np.asarray(t, dtype=float)
    a, v_max, t0 = -1.0, -1.5, 0.2
    t1 = t0 + v_max / a
    x = np.where(t < t0, 0.0, np.where(t < t1, 0.5 * a * (t - t0) ** 2,
                                       0.5 * a * (t1 - t0) ** 2 + v_max * (t - t1)))  # fmt: skip
    v = np.where(t < t0, 0.0, np.where(t < t1, a * (t - t0), v_max))
    return x, v


def test_the_experiment_used_off_axis_is_off_axis() -> None:
    assert OFF_AXIS.transducer_m != EXP.transducer_m


@pytest.mark.parametrize("exp", [EXP, OFF_AXIS], ids=["built-in", "off-axis"])
def test_the_table_is_the_geometry_of_the_motion(exp: Experiment) -> None:
    table = truth_table(exp, _ramp, 2.5)
    assert table.shape == (2501, 3)
    np.testing.assert_allclose(table[:, 0], np.arange(2501) * STEP_S, atol=1e-12)
    x, _ = _ramp(table[:, 0])
    np.testing.assert_allclose(table[:, 1], exp.range_at(x), rtol=0, atol=1e-12)
    # The closing speed is minus the range's rate (a central difference of the analytic
    # range, away from the two kinks of the ramp).
    h = 1e-6
    t = table[:, 0]
    rate = (exp.range_at(_ramp(t + h)[0]) - exp.range_at(_ramp(t - h)[0])) / (2 * h)
    smooth = (np.abs(t - 0.2) > 2e-3) & (np.abs(t - 1.7) > 2e-3)
    np.testing.assert_allclose(table[smooth, 2], -rate[smooth], atol=1e-6)
    assert table[0, 2] == 0.0 and table[-1, 2] != 0.0


def test_a_table_off_axis_projects_the_velocity() -> None:
    table = truth_table(OFF_AXIS, _ramp, 2.5)
    steady = table[:, 0] > 1.8
    # Closing along the stage at 1.5 m/s, seen off the line: less than 1.5 m/s, and changing.
    assert np.all(table[steady, 2] < 1.5) and np.ptp(table[steady, 2]) > 1e-3


@settings(max_examples=30, deadline=None)
@given(
    st.lists(st.tuples(st.floats(0.0, 100.0), st.floats(-20.0, 20.0)), min_size=2, max_size=40),
    st.floats(0.0, 200.0),
)
def test_a_written_table_reads_back_to_its_printed_precision(
    tmp_path_factory: pytest.TempPathFactory, rows: list[tuple[float, float]], t0: float
) -> None:
    t = t0 + np.arange(len(rows)) * STEP_S
    table = np.column_stack([t, [r for r, _ in rows], [v for _, v in rows]])
    path = write_truth(tmp_path_factory.mktemp("truth") / "truth-run-1.csv", table)
    back = read_truth(path)
    assert back.shape == table.shape
    np.testing.assert_allclose(back[:, 0], table[:, 0], rtol=0, atol=5e-7)
    np.testing.assert_allclose(back[:, 1:], table[:, 1:], rtol=0, atol=5e-8)
    assert path.read_text().splitlines()[0] == ",".join(COLUMNS)


def test_the_truth_between_rows_is_interpolated_and_nan_outside() -> None:
    table = np.array([[0.0, 10.0, 1.0], [0.001, 9.999, 1.0], [0.002, 9.998, 1.2]])
    got = truth_at(table, [-1e-4, 0.0, 0.0005, 0.0015, 0.002, 0.0021])
    np.testing.assert_allclose(got["range_m"], [np.nan, 10.0, 9.9995, 9.9985, 9.998, np.nan])
    np.testing.assert_allclose(got["speed_mps"], [np.nan, 1.0, 1.0, 1.1, 1.2, np.nan])


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            "t,r,v\n0,1,2\n",
            "--exact-truth = '{p}' is not allowed: must be a CSV whose header is "
            "'time_s,range_m,closing_speed_mps'; its header is 't,r,v': give the "
            "truth-run-N.csv that hil sim-serve tank --jack wrote beside its experiment file",
        ),
        (
            "time_s,range_m,closing_speed_mps\n0,1,2\n",
            "--exact-truth = '{p}' is not allowed: must be at least 2 rows of 3 numbers; it "
            "holds 1 row(s) of 3",
        ),
        (
            "time_s,range_m,closing_speed_mps\n0,1\n0.001,1\n",
            "--exact-truth = '{p}' is not allowed: must be at least 2 rows of 3 numbers; it "
            "holds 2 row(s) of 2",
        ),
        (
            "time_s,range_m,closing_speed_mps\n0,1,2\n0,1,2\n",
            "--exact-truth = '{p}' is not allowed: must be finite numbers with time_s "
            "increasing; the file is damaged: write it again with the run",
        ),
        (
            "time_s,range_m,closing_speed_mps\n0,1,2\n0.001,x,2\n",
            "--exact-truth = '{p}' is not allowed: must be rows of three numbers; the file is "
            "damaged (",
        ),
    ],
    ids=["header", "one-row", "two-columns", "times-not-increasing", "not-a-number"],
)
def test_a_file_that_is_not_a_truth_table_is_refused(
    tmp_path: Path, text: str, message: str
) -> None:
    path = tmp_path / "truth.csv"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        read_truth(path)
    assert str(err.value).startswith(message.format(p=path))


def test_a_missing_truth_file_is_named(tmp_path: Path) -> None:
    with pytest.raises(ConfigError) as err:
        read_truth(tmp_path / "nope.csv")
    assert str(err.value) == (
        f"--exact-truth = '{tmp_path / 'nope.csv'}' is not allowed: must be an existing file; "
        "check the path"
    )


def test_a_negative_duration_is_refused() -> None:
    with pytest.raises(ConfigError) as err:
        truth_table(EXP, _ramp, -1.0)
    assert str(err.value) == (
        "duration_s = -1.0 is not allowed: must be a finite number of seconds >= 0"
    )


class _Clock:
    def advance(self, audio_s: float) -> None:
        self.audio_s = audio_s


def _drive(client: TankJackClient, blocks: list[np.ndarray]) -> None:
    """Call the client's audio callback once per input block (the JACK server's part)."""
    time, out = BlockTime(), np.zeros((client.period, 2), dtype=np.float32)
    for k, x in enumerate(blocks):
        time.sample_index = 1000 + k * client.period  # the tank's stream began earlier
        client._callback(x.reshape(-1, 1), out, client.period, time, StatusFlags(0))


def test_the_jack_tank_writes_each_runs_truth_on_the_runs_time(tmp_path: Path) -> None:
    """A run's first transmitted sample is world time 0 (the tank finds it on its input),
    and its last sound ends the table: the rows are the carriage's, shifted by that origin."""
    period = 256
    asked: list[np.ndarray] = []

    def carriage(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        asked.append(np.asarray(t))
        return _ramp(t)

    client = TankJackClient(EXP, period, carriage, _Clock(), truth_dir=tmp_path)
    worlds = threading.Event()

    def world(x: np.ndarray, first: int) -> np.ndarray:
        return np.zeros((x.shape[0], 2), dtype=np.float32)

    # The world is armed by hand (building the tank's acoustics is not what is checked).
    client._armed = world
    onset = 100  # the run's first waveform sample arrives 100 samples into block 2
    first = client._first_nonzero
    sound = np.ones(period)
    blocks = [np.zeros(period), np.zeros(period)]
    head = np.zeros(period)
    head[onset + first :] = 1.0
    blocks += [head] + [sound] * 6 + [np.zeros(period)] * END_SILENT_BLOCKS
    render = threading.Thread(target=client._render, daemon=True)
    client._arm = lambda: worlds.set()  # type: ignore[method-assign]
    render.start()
    _drive(client, blocks)
    assert worlds.wait(60), "the worker never reached the run's end"
    client.close()
    origin = 1000 + 2 * period + onset
    sounding_until = 1000 + 9 * period
    path = tmp_path / "truth-run-1.csv"
    assert client.truth_files == [path]
    table = read_truth(path)
    duration = (sounding_until - origin) / EXP.waveform.fs_hz
    assert table[-1, 0] == pytest.approx(np.floor(duration / STEP_S) * STEP_S, abs=1e-9)
    shifted = truth_table(EXP, lambda t: _ramp(t + origin / EXP.waveform.fs_hz), duration)
    np.testing.assert_allclose(table, shifted, rtol=0, atol=5e-7)


def test_a_run_still_sounding_when_the_tank_closes_gets_its_truth(tmp_path: Path) -> None:
    client = TankJackClient(EXP, 256, _ramp, _Clock(), truth_dir=tmp_path)
    client._armed = lambda x, first: np.zeros((x.shape[0], 2), dtype=np.float32)
    block = np.ones(256)
    block[: client._first_nonzero] = 0.0
    _drive(client, [block])  # one block: the callback waits for no render yet
    client.close()
    table = read_truth(tmp_path / "truth-run-1.csv")
    assert table[0, 0] == 0.0 and table[-1, 0] == pytest.approx(0.001)
    np.testing.assert_allclose(
        table[:, 1], EXP.range_at(_ramp(1000 / EXP.waveform.fs_hz + table[:, 0])[0]), atol=5e-7
    )


@pytest.mark.slow
def test_hil_report_scores_a_recording_against_a_truth_table(
    short_virtual_outcome: RunOutcome, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run on the simulated board knows its exact truth in process; written as a table
    (at its estimates' bounce instants) and given back through ``hil report --exact-truth``,
    the rebuilt summary scores the recording against it exactly as the live run did."""
    from hil.cli.main import main
    from hil.experiments.run_scoring import bounce_times, summarize

    outcome = short_virtual_outcome
    assert outcome.exact_truth is not None
    live = summarize(outcome)
    t_b, first = np.unique(bounce_times(outcome), return_index=True)
    table = np.column_stack(
        [t_b, outcome.exact_truth["range_m"][first], outcome.exact_truth["speed_mps"][first]]
    )
    # The file keeps microseconds: one row more each side keeps the first and last bounce
    # instants inside the table once rounded.
    table = np.vstack([table[0] - [1e-3, 0, 0], table, table[-1] + [1e-3, 0, 0]])
    path = write_truth(tmp_path / "truth-run-1.csv", table)
    argv = ["report", str(outcome.folder / "run.h5"), "--exact-truth", str(path),
            "--out", str(tmp_path / "re"), "--no-map", "--json"]  # fmt: skip
    assert main(argv) == 0
    rebuilt = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    for key in ("range_rmse_vs_exact_m", "speed_rmse_vs_exact_mps", "telemetry_truth_error_max_m"):
        assert rebuilt[key] == pytest.approx(live[key], abs=2e-6), key
    assert rebuilt["range_rmse_m"] == live["range_rmse_m"]
    # A table that ends before the run's estimates do is another run's (or a cut one).
    short = write_truth(tmp_path / "cut.csv", table[: len(table) // 2])
    argv[3] = str(short)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert f"--exact-truth = '{short}' is not allowed: must be a table covering the run's " in err
    assert "give the truth-run-N.csv of this run" in err


def test_hil_report_refuses_a_missing_truth_file_before_reading_the_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], short_virtual_outcome: RunOutcome
) -> None:
    from hil.cli.main import main

    run = str(short_virtual_outcome.folder / "run.h5")
    missing = tmp_path / "truth-run-9.csv"
    assert main(["report", run, "--exact-truth", str(missing), "--out", str(tmp_path)]) == 2
    assert (
        capsys.readouterr()
        .err.strip()
        .endswith(
            f"--exact-truth = '{missing}' is not allowed: must be an existing file; check the path"
        )
    )
