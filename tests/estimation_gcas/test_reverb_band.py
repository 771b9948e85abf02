"""The default reverberation band: derived from the waveform, no ghost at its edge."""

from __future__ import annotations

import numpy as np
import pytest

from hil.errors import ConfigError
from hil.estimation.gcas import GcasReceiver
from hil.estimation.reverb_band import (
    auto_reverb_speed_mps,
    doppler_resolution_mps,
    edge_hypotheses,
    in_reverberation,
    is_diffuse,
    resolve_reverb_speed,
    reverberation_coherence,
)
from hil.experiments.experiment import DEFAULT_EXPERIMENT, parse_experiment
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule import HopSchedule

from .conftest import design_speed_target, echo_samples, run_blocks, true_range

TANK_TONES = np.array([57e3, 59e3, 61e3, 63e3])


def test_doppler_resolution_golden() -> None:
    # c / (2 f_lo T_h): tank-audio 1482.3 / (2 · 57 kHz · 10 ms) = 1.3003 m/s.
    assert doppler_resolution_mps(TANK_TONES, 0.01, 1482.3) == pytest.approx(1.30026, abs=1e-5)
    assert auto_reverb_speed_mps(TANK_TONES, 0.01, 1482.3) == pytest.approx(0.65013, abs=1e-5)


def test_resolve_auto_numbers_and_off() -> None:
    assert resolve_reverb_speed("auto", TANK_TONES, 0.01, 1482.3, 3.0) == pytest.approx(
        0.65013, 1e-4
    )
    assert resolve_reverb_speed(None, TANK_TONES, 0.01, 1482.3, 3.0) == pytest.approx(0.65013, 1e-4)
    # The band's edge (1.30 m/s) would cover a ±1.2 m/s span: no band.
    assert resolve_reverb_speed("auto", TANK_TONES, 0.01, 1482.3, 1.2) == 0.0
    assert resolve_reverb_speed(0.8, TANK_TONES, 0.01, 1482.3, 3.0) == 0.8
    assert resolve_reverb_speed(0, TANK_TONES, 0.01, 1482.3, 3.0) == 0.0


@pytest.mark.parametrize("bad", ["fast", True, [1.0]])
def test_resolve_refuses_what_is_not_a_speed(bad: object) -> None:
    with pytest.raises(ConfigError) as info:
        resolve_reverb_speed(bad, TANK_TONES, 0.01, 1482.3, 3.0)  # type: ignore[arg-type]
    msg = str(info.value)
    assert "reverb_speed_mps" in msg and repr(bad) in msg and "'auto' or a speed >= 0 m/s" in msg


@pytest.mark.parametrize("bad", [-0.5, float("nan"), float("inf")])
def test_resolve_refuses_negative_and_non_finite(bad: float) -> None:
    with pytest.raises(ConfigError, match="reverb_speed_mps"):
        resolve_reverb_speed(bad, TANK_TONES, 0.01, 1482.3, 3.0)


def test_edge_hypotheses_golden() -> None:
    w = np.array([1, 1, 1, 0, 0, 0, 1, 1, 1], dtype=float)
    assert edge_hypotheses(w, allow_in_band=False).tolist() == [0, 0, 1, 1, 1, 1, 1, 0, 0]
    assert edge_hypotheses(w, allow_in_band=True).tolist() == [0, 0, 1, 0, 0, 0, 1, 0, 0]
    assert not edge_hypotheses(np.ones(5), allow_in_band=False).any()


def _tank_schedule() -> HopSchedule:
    return check_design(get_preset("tank-audio").spec("random-cyclic"))


def _tank_receiver(**extra: object) -> GcasReceiver:
    # The peak readout through the tank's multipath: the detector's own (the refinement's
    # one-echo fit does not hold there; the tank run reads the first arrival).
    return GcasReceiver.from_options(
        _tank_schedule(), 192_000.0, sound_speed_mps=1482.3, max_speed_mps=3.0,
        max_range_m=12.0, m_hops=10, **{"refine": False, **extra},
    )  # fmt: skip


def _tank_echo(range_m: float, speed_mps: float, seed: int) -> np.ndarray:
    """A target in the tank plus its surface and bottom images (two weaker copies a few
    decimetres behind), 0 dB per-sample SNR."""
    s = _tank_schedule()
    x = echo_samples(s, range_m, speed_mps, 1.0, snr_db=0.0, seed=seed, fs_hz=192_000.0, c=1482.3)
    for extra_m, amp in ((0.2, -0.6), (0.23, 0.4)):
        x += echo_samples(
            s, range_m + extra_m, speed_mps, 1.0, fs_hz=192_000.0, c=1482.3, amplitude=amp
        )
    return x


def test_default_receiver_has_the_waveform_band() -> None:
    rx = _tank_receiver()
    assert rx.reverb_speed_mps == pytest.approx(0.65013, 1e-4)
    v = rx.grid.speeds_mps[rx.refused_hypotheses]
    # Refused: the band around zero Doppler and its edge, nothing beyond 1.5 m/s.
    assert v.size and np.max(np.abs(v)) < 1.5 and np.min(np.abs(v)) == pytest.approx(0, abs=0.05)
    assert not _tank_receiver(reverb_speed_mps=0.0).refused_hypotheses.any()


@pytest.mark.parametrize("speed", [0.0, 0.5, -0.7])
def test_a_target_inside_the_band_gives_no_ghost(speed: float) -> None:
    x = _tank_echo(6.0, speed, seed=5)
    rx = _tank_receiver()
    est = run_blocks(rx, x, 19_200)
    # No estimate at all (before the edge rule the peak sat on the band's edge, ~1.4 m/s).
    assert est == []
    assert rx.in_band_count > 20


@pytest.mark.parametrize("speed", [0.0, 0.5])
def test_with_the_band_off_a_slow_target_is_estimated(speed: float) -> None:
    x = _tank_echo(6.0, speed, seed=6)
    est = run_blocks(_tank_receiver(reverb_speed_mps=0.0), x, 19_200)
    assert len(est) >= 80
    v = np.array([e.speed_mps for e in est])
    assert np.all(np.abs(v - speed) < 0.3)


@pytest.mark.parametrize("speed", [2.4, -2.6])
def test_a_target_past_the_band_is_estimated_with_the_default(speed: float) -> None:
    x = _tank_echo(6.0, speed, seed=7)
    est = run_blocks(_tank_receiver(), x, 19_200)
    assert len(est) >= 80
    v = np.array([e.speed_mps for e in est])
    assert np.all(np.abs(v - speed) < 0.3)


def test_default_band_costs_at_ghost_speeds() -> None:
    # att tones 1.1 kHz apart: a stationary echo of one tone looks like the next tone at
    # ±27.5 m/s, so those cells are masked; a 25 m/s target keeps its estimates but loses
    # speed accuracy (0.02 m/s rms with the band off).
    _, est = design_speed_target()
    assert len(est) >= 50
    dv = np.array([e.speed_mps - 25.0 for e in est])
    # Measured 0.34 m/s rms (the Doppler readout's interpolation next to masked cells; the
    # grid step is 0.95 m/s here) and 0.049 m in range (0.03 m with the band off).
    assert np.sqrt(np.mean(dv**2)) < 0.45
    dr = np.array([e.range_m - true_range(60.0, 25.0, e.t_tx_s, e.t_s) for e in est])
    assert np.sqrt(np.mean(dr**2)) < 0.07


def _with_options(options: str) -> str:
    """The built-in file with ``options`` (inline-table entries) added to its receiver's."""
    line = 'options = { background = "simulated" }'
    assert line in DEFAULT_EXPERIMENT
    return DEFAULT_EXPERIMENT.replace(line, f'options = {{ background = "simulated", {options} }}')


def test_tank_run_derives_the_band_from_the_tow() -> None:
    exp = parse_experiment(DEFAULT_EXPERIMENT)
    # The default tow (1.5 m/s) is within two resolution cells (2 × 1.30 m/s): no band.
    assert exp.receiver_options["reverb_speed_mps"] == 0.0
    # A tank has multipath: the first-arrival readout (192 kHz × 0.17 s period = 32640).
    assert exp.receiver_options["range_readout"] == "first-arrival"
    fast = parse_experiment(DEFAULT_EXPERIMENT.replace("speed_mps = 1.5", "speed_mps = 2.8"))
    assert fast.receiver_options["reverb_speed_mps"] == "auto"
    given = parse_experiment(_with_options("reverb_speed_mps = 0.3"))
    assert given.receiver_options["reverb_speed_mps"] == 0.3
    peak = parse_experiment(_with_options('range_readout = "peak"'))
    # With the peak readout in a tank the refinement is off unless the file sets it.
    assert peak.receiver_options == {
        "background": "simulated",
        "range_readout": "peak",
        "reverb_speed_mps": 0.0,
        "refine": False,
    }
    refined = parse_experiment(_with_options('range_readout = "peak", refine = true'))
    assert refined.receiver_options["refine"] is True


@pytest.mark.parametrize(
    ("option", "message"),
    [
        ('reverb_speed_mps = "fast"', "receiver.options.reverb_speed_mps = 'fast' is not allowed"),
        ("reverb_speed_mps = -1.0", "receiver.options.reverb_speed_mps = -1.0 is not allowed"),
        (
            'range_readout = "centre"',
            "receiver.options.range_readout = 'centre' is not allowed: must be one of peak, "
            "first-arrival",
        ),
    ],
)
def test_tank_receiver_options_refused_when_the_file_is_read(option: str, message: str) -> None:
    text = _with_options(option)
    with pytest.raises(ConfigError) as info:
        parse_experiment(text)
    assert str(info.value).startswith(message)


@pytest.mark.parametrize("snr_db", [-3.0, 0.0, 3.0, 10.0])
def test_the_coherence_expected_in_measured_interference_is_what_one_echo_has(
    snr_db: float,
) -> None:
    # One echo of unit amplitude in M = 10 hops, each hop's term with complex Gaussian
    # interference of per-hop SNR snr_db, measured on three other tones of the same windows:
    # the coherence the function expects is the mean coherence of such echoes. Measured
    # (expected / mean coherence): 0.373 / 0.389 at -3 dB, 0.517 / 0.540 at 0 dB, 0.682 /
    # 0.693 at 3 dB, 0.917 / 0.918 at 10 dB (the ratio measured from 30 cells reads a little
    # low, which lets an echo pass a little more easily).
    rng = np.random.default_rng(8)
    m, trials = 10, 4000
    power = 10 ** (-snr_db / 10.0)

    def interference(*shape: int) -> np.ndarray:
        return np.sqrt(power / 2.0) * (rng.normal(size=shape) + 1j * rng.normal(size=shape))

    on = 1.0 + interference(trials, m)
    off = interference(trials, m, 3)
    rho = np.abs(on.sum(axis=1)) ** 2 / (m * np.sum(np.abs(on) ** 2, axis=1))
    expected = [reverberation_coherence(on[i], off[i]) for i in range(trials)]
    assert np.mean(expected) == pytest.approx(np.mean(rho), abs=0.03)


def test_only_echoes_slower_than_one_doppler_cell_share_the_reverberation() -> None:
    # att: c / (2 · 28350 Hz · 10 ms) = 2.646 m/s at 1500 m/s.
    tones = [28350.0, 29450.0, 30550.0, 31650.0]
    assert in_reverberation(2.6, tones, 0.01, 1500.0)
    assert in_reverberation(-2.6, tones, 0.01, 1500.0)
    assert not in_reverberation(2.7, tones, 0.01, 1500.0)


def test_diffuse_needs_the_tones_coherence_to_hold_above_the_whole() -> None:
    assert is_diffuse(0.53, 0.86, 0.8)
    assert not is_diffuse(0.53, 0.7, 0.8)  # not coherent within the tones either: no echo
    assert not is_diffuse(0.9, 0.85, 0.8)  # the whole holds better: a point echo
