"""The tank's own echoes, directivity and clipping in the composed channel and in scenarios,
and the planned-level check of the built-in tank."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from sim_devices.acoustics.channel import TOP_CODE, clip_full_scale
from sim_devices.acoustics.directivity import TableBeam
from sim_devices.acoustics.scenario import build_channel, parse_scenario
from sim_devices.acoustics.tank_response import specular_paths

SCENARIO: dict[str, Any] = {
    "preset": "tank-audio",
    "duration_s": 0.05,
    "sonar": {"position_m": [0.5, 2.0, -1.0], "source_level_db": 180.0,
              "sensitivity_db": -200.0, "gain_db": 40.0},
    "targets": [{"trajectory": "fixed", "position_m": [8.0, 2.0, -1.0],
                 "target_strength_db": -20.0}],
    "tank": {"size_m": [12.0, 4.0, 2.5], "wall_reflection": 0.8, "bottom_reflection": 0.7},
}  # fmt: skip


def _with(**tank: Any) -> dict[str, Any]:
    return {**SCENARIO, "tank": {**SCENARIO["tank"], **tank}}


def test_clip_counts_what_is_beyond_full_scale() -> None:
    x = np.array([0.0, 0.999, 1.0, -1.0, -1.0001, 7.0])
    y, over = clip_full_scale(x)
    assert over == 3 and y.tolist() == [0.0, 0.999, TOP_CODE, -1.0, -1.0, TOP_CODE]


def test_the_near_wall_clips_an_omni_tank_audio_sonar_and_it_is_counted() -> None:
    ch = build_channel(parse_scenario(_with(own_echoes=True)))
    parts = ch.read_components(5000)
    # the wall 0.5 m behind alone: 0.8 / 1 m at 180 dB and -160 dB, 11.3 × full scale
    assert ch.tank is not None
    near = specular_paths(ch.tank, (0.5, 2.0, -1.0), (0.5, 2.0, -1.0), 1, ch.sound_speed_mps)
    amp = near.amplitude[0] * ch.amplitude * ch.receiver.volts_per_upa
    assert near.distance_m[0] == pytest.approx(1.0) and amp == pytest.approx(11.31, abs=0.01)
    assert float(np.max(np.abs(parts["input_fs"]))) > amp
    beyond = int(np.count_nonzero((parts["input_fs"] > TOP_CODE) | (parts["input_fs"] < -1)))
    assert ch.clipped_samples == beyond > 1000
    assert np.max(parts["received"]) <= TOP_CODE and np.min(parts["received"]) >= -1.0
    # the components add up to the pressure
    total = sum(parts[k] for k in ("echo", "direct", "tank", "reverberation", "noise"))
    assert np.array_equal(total, parts["pressure"])


def test_own_echoes_off_by_default_and_switchable() -> None:
    off = build_channel(parse_scenario(SCENARIO))
    assert not np.any(off.read_components(2000)["tank"])
    assert off.clipped_samples == 0
    specular = build_channel(parse_scenario(_with(own_echoes=True, late_tail=False)))
    full = build_channel(parse_scenario(_with(own_echoes=True)))
    a, b = specular.read_components(20000)["tank"], full.read_components(20000)["tank"]
    assert np.sum(b**2) > np.sum(a**2) > 0  # the tail adds energy


def test_a_projector_pointed_at_the_target_hears_less_of_the_tank() -> None:
    beam = {"type": "piston", "radius_m": 0.03, "axis": [1.0, 0.0, 0.0]}
    omni = build_channel(parse_scenario(_with(own_echoes=True, late_tail=False)))
    sc = _with(own_echoes=True, late_tail=False)
    sc["sonar"] = {**sc["sonar"], "beam": beam, "hydrophone_beam": {"type": "omni"}}
    piston = build_channel(parse_scenario(sc))
    p_omni = omni.read_components(20000)
    p_piston = piston.read_components(20000)
    # the target is on the axis: its direct echo is unchanged, the tank's echoes are weaker
    assert np.array_equal(piston._echoes[0].block(0, 4000), omni._echoes[0].block(0, 4000))
    assert np.sum(p_piston["tank"] ** 2) < 0.05 * np.sum(p_omni["tank"] ** 2)


def test_a_table_beam_is_read_from_the_scenario() -> None:
    sc = dict(SCENARIO)
    sc["sonar"] = {**sc["sonar"], "beam": {"type": "table", "angles_deg": [0, 90, 180],
                                           "levels_db": [0, -10, -30]}}  # fmt: skip
    parsed = parse_scenario(sc)
    assert isinstance(parsed.beam, TableBeam) and isinstance(parsed.hydrophone_beam, TableBeam)


def test_bad_tank_echo_settings_name_the_field() -> None:
    moving = _with(own_echoes=True)
    moving["sonar"] = {**moving["sonar"], "velocity_mps": [0.1, 0.0, 0.0]}
    with pytest.raises(ConfigError, match=r"tank\.own_echoes = True .*a sonar at rest"):
        parse_scenario(moving)
    with pytest.raises(ConfigError, match=r"tank\.image_order = 5 .*<= 4"):
        parse_scenario(_with(image_order=5))
    with pytest.raises(ConfigError, match=r"tank\.t60_formula = 'norris' .*eyring, sabine"):
        parse_scenario(_with(own_echoes=True, t60_formula="norris"))
    with pytest.raises(ConfigError, match=r"sonar\.beam\.type = 'cardioid'"):
        parse_scenario({**SCENARIO, "sonar": {"beam": {"type": "cardioid"}}})


def test_the_built_in_tank_plans_its_levels_and_warns_before_a_run_that_clips(
    caplog: pytest.LogCaptureFixture,
) -> None:
    from hil.experiments.sim_tank import planned_adc_peak_fs
    from hil.experiments.tank_run import LiveView, _planned_levels

    quiet = parse_experiment(DEFAULT_EXPERIMENT)
    assert 0.0 < planned_adc_peak_fs(quiet) < 1.0
    loud = parse_experiment(DEFAULT_EXPERIMENT.replace("gain_db = 10.0", "gain_db = 70.0"))
    with caplog.at_level(logging.WARNING, logger="hil.run"):
        peak = _planned_levels(loud, LiveView(enabled=False))
    assert peak is not None and peak > 1.0
    assert peak == pytest.approx(planned_adc_peak_fs(quiet) * 1000.0, rel=1e-6)
    assert "the planned levels clip the ADC" in caplog.text


def test_the_experiment_file_refuses_bad_tank_physics_naming_the_key() -> None:
    cases = [
        ("image_order = 1", "image_order = 5", r"simulation\.image_order = 5 .*<= 4"),
        ("tank_echo_order = 3", "tank_echo_order = 41", r"simulation\.tank_echo_order = 41"),
        ('transducer_beam = "piston"', 'transducer_beam = "cardioid"',
         r"simulation\.transducer_beam = 'cardioid' .*omni, piston"),
        ("transducer_radius_m = 0.015", "transducer_radius_m = 0.0",
         r"simulation\.transducer_radius_m = 0\.0 .*> 0"),
        ("tank_echoes = true", 'tank_echoes = "yes"', r"simulation\.tank_echoes = 'yes'"),
    ]  # fmt: skip
    for old, new, message in cases:
        assert old in DEFAULT_EXPERIMENT
        with pytest.raises(ConfigError, match=message):
            parse_experiment(DEFAULT_EXPERIMENT.replace(old, new))
