"""The composed channel, scenarios, truth and ``hil simulate``."""

from __future__ import annotations

import copy
from pathlib import Path

import numpy as np
import pytest
from scipy.io import wavfile

from hil.cli.main import main
from hil.errors import ConfigError
from hil.signals.presets import check_design, get_preset
from sim_devices.acoustics.channel import Channel, DirectBlast, Target, source_amplitude
from sim_devices.acoustics.noise_generator import ShapedNoiseGenerator
from sim_devices.acoustics.propagation import spherical_transmission_loss
from sim_devices.acoustics.scenario import build_channel, parse_scenario
from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed, Live
from sim_devices.acoustics.truth import hop_truth

FS = 100_000.0
SCHED = check_design(get_preset("att").spec("random-cyclic"))


def _flat(level: float):
    return lambda f: np.full(np.shape(f), level)


def test_simulated_snr_matches_the_sonar_equation() -> None:
    sonar = Fixed((0.0, 0.0, -10.0))
    band = (20_000.0, 40_000.0)
    nsl, absorption, r = 50.0, 8.0, 40.0
    noise = ShapedNoiseGenerator(_flat(nsl), FS, band, seed=3, n_taps=2049)
    ch = Channel(
        SCHED, FS, sonar, 200.0, 1500.0,
        targets=[Target(Fixed((r, 0.0, -10.0)), -5.0)], absorption_db_per_km=absorption,
        noise=noise,
    )  # fmt: skip
    parts = ch.read_components(int(0.5 * FS))
    snr_sim = 10 * np.log10(np.mean(parts["echo"][10000:] ** 2) / np.var(parts["noise"]))
    # Active, noise-limited: SNR = SL - 2 TL + TS - NL, NL = spectrum level + 10 log10(B / 1 Hz).
    noise_level = nsl + 10 * np.log10(band[1] - band[0])
    snr_eq = 200.0 - 2 * spherical_transmission_loss(r, absorption) - 5.0 - noise_level
    assert abs(snr_sim - snr_eq) < 0.5


def test_calibration_to_counts() -> None:
    sonar = Fixed((0.0, 0.0, 0.0))
    ch = Channel(SCHED, FS, sonar, 160.0, 1500.0, targets=[Target(Fixed((10.0, 0, 0)), 0.0)])
    parts = ch.read_components(2000)
    peak = np.max(np.abs(parts["echo"][1400:]))
    assert peak == pytest.approx(source_amplitude(160.0) / 100.0, rel=1e-3)
    assert np.allclose(parts["received"], parts["pressure"] * 10 ** (-180 / 20))


def test_direct_blast_delay_and_level() -> None:
    sonar = Fixed((0.0, 0.0, -5.0))
    ch = Channel(SCHED, FS, sonar, 180.0, 1500.0, direct_blast=DirectBlast(-20.0, 0.15))
    d = ch.read_components(300)["direct"]
    t = np.arange(300) / FS
    expected = source_amplitude(180.0) * 0.1 / 0.15 * SCHED.evaluate(t - 0.15 / 1500.0)
    assert np.allclose(d, expected, rtol=1e-9, atol=1e-6 * np.max(np.abs(expected)))


def test_live_trajectory_gives_the_constant_velocity_echo() -> None:
    cv = ConstantVelocity((30.0, 0.0, 0.0), (-2.0, 0.0, 0.0))
    live = Live(lambda t: cv.position(t))
    sonar = Fixed((0.0, 0.0, 0.0))
    a = Channel(SCHED, FS, sonar, 180.0, 1500.0, targets=[Target(cv)]).read_components(5000)
    b = Channel(SCHED, FS, sonar, 180.0, 1500.0, targets=[Target(live)]).read_components(5000)
    assert np.array_equal(a["echo"], b["echo"])


def _scenario(**extra) -> dict:
    base = {
        "preset": "att", "duration_s": 0.05, "seed": 4,
        "sonar": {"position_m": [0.0, 0.0, -20.0], "velocity_mps": [3.0, 0.0, 0.0]},
        "targets": [{"trajectory": "radial", "range_m": 30.0, "speed_mps": 5.0}],
        "noise": {"sea_state": 2},
        "reverberation": {"srr_db": 5.0, "density_per_m3": 0.02, "max_range_m": 40.0,
                          "frame_samples": 1024},
        "direct_blast": {"coupling_db": -30.0},
    }  # fmt: skip
    base.update(extra)
    return base


def test_channel_chunks_equal_whole() -> None:
    sc = parse_scenario(_scenario())
    whole = build_channel(sc).read(5000)
    ch = build_channel(sc)
    parts = np.concatenate([ch.read(k) for k in (7, 1993, 3000)])
    assert np.array_equal(whole, parts)


def test_requested_srr_and_snr_set_the_levels() -> None:
    sc = parse_scenario(_scenario(noise={"snr_db": 12.0}))
    ch = build_channel(sc)
    assert ch.reverberation is not None
    ratio = ch.echo_power(0) / ch.reverberation.expected_power(0.0)
    assert 10 * np.log10(ratio) == pytest.approx(5.0, abs=1e-9)
    parts = ch.read_components(20000)
    snr = 10 * np.log10(ch.echo_power(0) / np.var(parts["noise"]))
    assert abs(snr - 12.0) < 0.5


def test_tank_image_paths_change_the_echo() -> None:
    tank = {"size_m": [12.0, 4.0, 2.5], "image_order": 1}
    sc = {"preset": "tank-audio", "duration_s": 0.01, "sonar": {"position_m": [0.5, 2, -1]},
          "targets": [{"trajectory": "fixed", "position_m": [6.0, 2.0, -1.0]}]}  # fmt: skip
    with_tank = build_channel(parse_scenario({**sc, "tank": tank}))
    free = build_channel(parse_scenario(sc))
    # Order 1 per round trip: the direct echo and 6 images on either leg.
    assert len(with_tank._echoes) == 13 and len(free._echoes) == 1
    n = 4000
    a, b = with_tank.read_components(n)["echo"], free.read_components(n)["echo"]
    assert not np.allclose(a, b)
    # the direct path is the same in both
    assert np.array_equal(with_tank._echoes[0].block(0, n), b)


def test_truth_range_and_speed() -> None:
    sonar = Fixed((0.0, 0.0, 0.0))
    target = ConstantVelocity((60.0, 0.0, 0.0), (-10.0, 0.0, 0.0))
    rows = hop_truth(SCHED, sonar, target, 1500.0, 0.3, 0.1)
    assert len(rows) >= 25
    for r in rows:
        assert 1500.0 * (r.t_rx_s - r.t_tx_s) / 2 == pytest.approx(r.range_m, abs=1e-6)
        assert r.radial_speed_mps == pytest.approx(10.0)
        assert r.alpha == pytest.approx(1510.0 / 1490.0, rel=1e-12)


@pytest.mark.parametrize(
    ("patch", "message"),
    [
        ({"colour": 1}, r"colour = 1 is not allowed: must be one of the keys"),
        (
            {"targets": [{"trajectory": "radial", "range_m": 30.0, "speed_mps": 1600.0}]},
            r"targets\[0\].speed_mps = 1600.0 .*\|v\| < sound speed",
        ),
        (
            {"targets": [{"trajectory": "radial", "range_m": -3.0}]},
            r"targets\[0\].range_m = -3.0 .*> 0 m",
        ),
        ({"fs_hz": 50000.0}, r"fs_hz = 50000.0 .*Nyquist"),
        ({"sonar": {"position_m": [0, 0, 0], "speed": 3}}, r"sonar.speed = 3 .*one of the keys"),
        ({"reverberation": {"density": 1}}, r"reverberation.density = 1 .*one of the keys"),
    ],
)
def test_bad_scenarios_are_refused_naming_the_field(patch: dict, message: str) -> None:
    data = _scenario(**copy.deepcopy(patch))
    with pytest.raises(ConfigError, match=message):
        parse_scenario(data)


def test_target_outside_the_tank_is_refused() -> None:
    sc = {"preset": "tank-audio", "tank": {"size_m": [5.0, 4.0, 2.0]},
          "sonar": {"position_m": [0.5, 2, -1]},
          "targets": [{"trajectory": "fixed", "position_m": [6.0, 2.0, -1.0]}]}  # fmt: skip
    with pytest.raises(ConfigError, match=r"targets\[0\] position at t = 0 s .*inside the tank"):
        parse_scenario(sc)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["att", "tank-audio", "tank-board"])
def test_every_example_scenario_runs(tmp_path: Path, name: str) -> None:
    status = main(["simulate", name, "--out",
                   str(tmp_path), "--duration", "0.02", "--quiet"])  # fmt: skip
    assert status == 0
    for f in ("received.wav", "schedule.json", "truth.csv", "truth.json"):
        assert (tmp_path / f).stat().st_size > 0
    fs, data = wavfile.read(tmp_path / "received.wav")
    received = data if data.ndim == 1 else data[:, 0]
    assert data.dtype == np.float32 and np.all(np.abs(received) < 1.0)
    assert data.shape[0] == round(0.02 * fs)


def test_cli_bad_scenario_exits_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.toml"
    bad.write_text('preset = "att"\n[sonar]\nvelocity_mps = [2000.0, 0.0, 0.0]\n')
    assert main(["simulate", str(bad), "--out", str(tmp_path / "o")]) == 2
    assert "sonar.velocity_mps = 2000.0" in capsys.readouterr().err
