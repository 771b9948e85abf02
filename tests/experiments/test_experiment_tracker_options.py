"""Tracker settings in an experiment file: ``track_*`` receiver options reach the tracker of
the run's receiver (and its recorded settings); a bad one is refused when the file is read."""

from __future__ import annotations

import pytest

from hil.errors import ConfigError
from hil.estimation.tracking import TrackedReceiver, TrackerSettings
from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from hil.experiments.tank_run import receiver_setup
from hil.recording.replay import build_receiver

MARK = 'options = { background = "simulated" }'


def _with_options(lines: str) -> str:
    """The built-in file with ``lines`` (``key = value`` each) as its receiver's options;
    its receiver gcas-mti, which needs no empty-tank capture to be built."""
    assert MARK in DEFAULT_EXPERIMENT
    inline = ", ".join(lines.split("\n"))
    return DEFAULT_EXPERIMENT.replace(MARK, f"options = {{ {inline} }}").replace(
        'name = "gcas-bg"', 'name = "gcas-mti"'
    )


def test_track_options_reach_the_runs_tracker() -> None:
    exp = parse_experiment(_with_options("track_confirm_hits = 4\ntrack_gate_sigmas = 3.5"))
    setup = receiver_setup(exp)
    assert (setup.settings["track_confirm_hits"], setup.settings["track_gate_sigmas"]) == (4, 3.5)
    receiver = build_receiver(setup, exp.schedule, 192_000.0)  # the built-in run's rate
    assert isinstance(receiver, TrackedReceiver)
    assert receiver.tracker.settings == TrackerSettings(confirm_hits=4, gate_sigmas=3.5)
    assert receiver.tracker.hop_s == pytest.approx(exp.schedule.period_s / exp.schedule.period_hops)


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ("track_confirm_hits = 0", "receiver.options.track_confirm_hits = 0 is not allowed: "
         "must be an integer >= 1; e.g. track_confirm_hits=3"),
        ("track_accel_mps2 = -2.0", "receiver.options.track_accel_mps2 = -2.0 is not allowed: "
         "must be a finite number >= 0; e.g. track_accel_mps2=10.0"),
        ("track_gate = 3.0", "receiver.options.track_gate = 3.0 is not allowed: must be a "
         "tracker setting: track_accel_mps2, "),
    ],
)  # fmt: skip
def test_a_bad_track_option_is_refused_when_the_file_is_read(line: str, message: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_experiment(_with_options(line))
    assert str(err.value).startswith(message)
