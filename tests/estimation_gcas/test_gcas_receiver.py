"""GCAS receiver: accuracy on exact moving-target echoes, false alarms, streaming contract."""

from __future__ import annotations

import functools
import itertools
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.estimation.base import Estimate, Receiver
from hil.estimation.baseband import ComplexBaseband
from hil.estimation.crlb import e_over_n0_db, schedule_crlb
from hil.estimation.gcas import GcasReceiver
from hil.estimation.registry import make_receiver
from hil.estimation.unit_correlators import UnitCorrelatorBank
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule import HopSchedule

from .conftest import (
    FS,
    LONE_TARGET_R0_M,
    C,
    att_schedule,
    echo_samples,
    lone_target_two_stage,
    make_gcas,
    preset_schedule,
    run_blocks,
    true_range,
)

_receiver = make_gcas
_run = run_blocks


def _errors(est: list[Estimate], r0: float, v: float) -> tuple[np.ndarray, np.ndarray]:
    dr = np.array([e.range_m - true_range(r0, v, e.t_tx_s, e.t_s) for e in est])
    dv = np.array([e.speed_mps - v for e in est])
    return dr, dv


def crlb_range_m(schedule: HopSchedule, m_hops: int, snr_db: float) -> float:
    """Range CRLB (m) for an M-hop codeword: σ_τ = 1/(π√8 B_rms √(E/N0)), B_rms from the
    spectrum of the actual M-hop waveform within the occupied band (± one 1/T_h)."""
    fs = FS
    hop = schedule.hop_s
    t = np.arange(int(round(m_hops * hop * fs))) / fs
    z = schedule.evaluate_analytic(t)
    spec = np.abs(np.fft.fft(z, 8 * z.shape[0])) ** 2
    f = np.fft.fftfreq(8 * z.shape[0], 1 / fs)
    lo, hi = schedule.tones_hz.min() - 1 / hop, schedule.tones_hz.max() + 1 / hop
    band = (f >= lo) & (f <= hi)
    w = spec[band] / spec[band].sum()
    f0 = float(np.sum(w * f[band]))
    b_rms = math.sqrt(float(np.sum(w * (f[band] - f0) ** 2)))
    # Per-sample SNR = (A²/2)/σ²; E = M T A²/2, N0 = 2σ²/fs.
    e_over_n0 = 10 ** (snr_db / 10) * m_hops * hop * fs / 2.0
    sigma_tau = 1.0 / (math.pi * math.sqrt(8.0) * b_rms * math.sqrt(e_over_n0))
    return C * sigma_tau / 2.0


def test_is_a_receiver_and_registered(rc_schedule: HopSchedule) -> None:
    rx = make_receiver(
        "gcas", rc_schedule, FS, sound_speed_mps=C, max_speed_mps=30.0, max_range_m=100.0,
        m_hops=10,
    )  # fmt: skip
    assert isinstance(rx, Receiver) and isinstance(rx, GcasReceiver)
    assert rx.fs_bb == pytest.approx(FS / 12) and rx.grid.size == 64


@pytest.mark.parametrize("speed", [12.0, -8.0, 25.0])
def test_high_snr_tracks_range_speed_and_codeword(rc_schedule: HopSchedule, speed: float) -> None:
    r0 = LONE_TARGET_R0_M
    # A lone target in white noise: no reverberation band (its ghost-speed cells near
    # ±27.5 m/s would cost the 25 m/s case accuracy: test_default_band_costs_at_ghost_speeds).
    est = list(lone_target_two_stage(speed)[1])
    assert len(est) >= 50  # one per hop once M hops have arrived
    dr, dv = _errors(est, r0, speed)
    assert np.sqrt(np.mean(dr**2)) < 0.03
    assert np.sqrt(np.mean(dv**2)) < 0.15
    hops = np.array([e.hop_index for e in est])
    assert np.all(np.diff(hops) == 1)  # the codeword advances by one per hop
    assert [e.codeword for e in est] == [h % rc_schedule.period_hops for h in hops.tolist()]
    # t_tx is the transmit end of that hop.
    ends = np.array([(h + 1) * rc_schedule.hop_s for h in hops.tolist()])
    assert np.allclose([e.t_tx_s for e in est], ends, atol=1e-9)


def test_errors_shrink_with_snr_and_stay_within_a_crlb_multiple(rc_schedule: HopSchedule) -> None:
    r0, v = 45.0, 15.0
    rms = []
    for snr in (-15.0, -5.0, 5.0):
        x = echo_samples(rc_schedule, r0, v, 0.7, snr_db=snr, seed=11)
        est = _run(_receiver(rc_schedule), x)
        dr, _ = _errors(est, r0, v)
        assert len(est) >= 40
        rms.append(float(np.sqrt(np.mean(dr**2))))
    assert rms[0] > rms[1] > rms[2]
    # Noncoherent GCAS uses energy only: its range error is set by the hop envelope, not by
    # B_w. Stated multiple at 5 dB per-sample SNR (E/N0 = 39 dB over M = 10 hops).
    bound = crlb_range_m(rc_schedule, 10, 5.0)
    assert rms[2] < 60 * bound


@pytest.mark.parametrize(("snr_db", "coh_multiple"), [(-5.0, 3.0), (0.0, 6.0)])
def test_coherent_sum_is_closer_to_the_crlb(
    rc_schedule: HopSchedule, snr_db: float, coh_multiple: float
) -> None:
    # The detector's own readouts (refinement off). Measured (seed 12, 60 estimates each):
    # coherent 2.0x / 3.9x the M-hop CRLB at -5 / 0 dB per-sample SNR (1.8 / 1.0 mm),
    # noncoherent 11x / 17x; the coherent form also refines the speed (2 mm/s rms noiseless
    # against 40 mm/s noncoherent).
    r0, v = 45.0, 15.0
    x = echo_samples(rc_schedule, r0, v, 0.7, snr_db=snr_db, seed=12)
    est_non = _run(_receiver(rc_schedule, refine=False), x)
    est_coh = _run(_receiver(rc_schedule, coherent=True, refine=False), x)
    assert len(est_coh) == len(est_non) >= 55
    window = 10 * rc_schedule.hop_s
    bound = schedule_crlb(
        rc_schedule, FS, 0.0, window, e_over_n0_db(snr_db, FS / 2, window), C
    ).sigma_range_m
    rms_non = float(np.sqrt(np.mean(_errors(est_non, r0, v)[0] ** 2)))
    dr_coh, dv_coh = _errors(est_coh, r0, v)
    rms_coh = float(np.sqrt(np.mean(dr_coh**2)))
    assert rms_coh < coh_multiple * bound
    assert rms_non > 2.5 * rms_coh
    assert np.sqrt(np.mean(dv_coh**2)) < 0.05
    hops = np.array([e.hop_index for e in est_coh])
    assert np.all(np.diff(hops) == 1)


def test_coherent_phase_model_matches_the_unit_correlators(rc_schedule: HopSchedule) -> None:
    # The phase of u for a window covering echo hop i of a·s(α(t − τ0)) (gcas.readout.
    # Readout._coherent_refine): φ_i − 2π f (α τ0 + t_i) − 2π ν_d g + 2π (α − α_d) f c_i.
    r0 = 40.0
    for v, dv in ((12.0, 0.0), (-8.0, 0.0), (12.0, 0.5), (-8.0, -0.4)):
        alpha, tau0 = (C + v) / (C - v), 2 * r0 / (C + v)
        a_d = (C + v + dv) / (C - v - dv)
        bb = ComplexBaseband(FS, 30_000.0, decimation=12, passband_hz=3141.0)
        y = bb.process(echo_samples(rc_schedule, r0, v, 0.3))
        fsb, g = bb.fs_out_hz, bb.group_delay / FS
        exact = rc_schedule.hop_s * fsb / a_d
        n_len = int(round(exact))
        nu = a_d * rc_schedule.tones_hz - 30_000.0
        u = UnitCorrelatorBank(fsb, nu[None, :], [n_len]).process(y)[:, 0, :]
        tab = rc_schedule.hops(8, 12)
        for i in range(12):
            f, t_i, phi = tab.freq_hz[i], tab.start_s[i], tab.phase_rad[i]
            k = int(tab.tone_index[i])
            end = tau0 + (t_i + rc_schedule.hop_s) / alpha
            centre = tau0 + (t_i + 0.5 * rc_schedule.hop_s) / alpha
            n = int(round((end - (exact - n_len + 1) / (2 * fsb)) * fsb + bb.group_delay / 12))
            predicted = (
                phi - 2 * np.pi * f * (alpha * tau0 + t_i) - 2 * np.pi * nu[k] * g
                + 2 * np.pi * (alpha - a_d) * f * centre
            )  # fmt: skip
            assert abs(np.angle(u[n, k] * np.exp(-1j * predicted))) < 0.05, (v, dv, i)
            # Amplitude a/2 per sample over the window, less the sinc loss when α_d ≠ α.
            assert 0.85 * 0.5 * n_len < abs(u[n, k]) < 1.02 * 0.5 * n_len


@pytest.mark.slow
def test_noise_only_false_alarm_rate_matches_the_configured_pfa(rc_schedule: HopSchedule) -> None:
    # The detector's own rate (refinement off); the refinement then refuses most of those
    # detections as no echo of the schedule (their hops' phases are unrelated).
    x = np.random.default_rng(21).normal(size=int(6.0 * FS))
    hops = 6.0 / rc_schedule.hop_s
    for pfa in (0.02, 0.2):
        rx = _receiver(rc_schedule, pfa=pfa, refine=False)
        detected = len(_run(rx, x, block=50_000))
        assert pfa / 4 < detected / hops < pfa * 4, (pfa, detected / hops)
        refined = _receiver(rc_schedule, pfa=pfa)
        kept = len(_run(refined, x, block=50_000))
        assert kept <= 0.2 * detected and refined.incoherent_count >= 0.8 * detected


@functools.cache
def _chunks_input_and_whole() -> tuple[np.ndarray, tuple[Estimate, ...]]:
    """The chunks == whole input (0.4 s, one echo at -10 dB) and its estimates in one block,
    computed once per process: every example compares its blocks against the same run (the
    array and the frozen estimates are read only)."""
    schedule = att_schedule()
    x = echo_samples(schedule, 30.0, -10.0, 0.4, snr_db=-10.0, seed=2)
    x.setflags(write=False)
    return x, tuple(_run(_receiver(schedule), x, block=x.shape[0]))


@settings(max_examples=6, deadline=None)
@given(st.lists(st.integers(1, 40_000), min_size=1, max_size=5))
def test_chunks_equal_whole(cuts: list[int]) -> None:
    schedule = att_schedule()
    x, cached = _chunks_input_and_whole()
    whole = list(cached)
    rx = _receiver(schedule)
    edges = sorted({0, x.shape[0], *(c % x.shape[0] for c in cuts)})
    parts: list[Estimate] = []
    for a, b in itertools.pairwise(edges):
        parts += rx.process(x[a:b])
    parts += rx.flush()
    assert parts == whole and len(whole) > 10


def test_range_folds_by_code_periods_beyond_one_period(rc_schedule: HopSchedule) -> None:
    # 95 m: the echo of hop i arrives more than half a period later; detections late in the
    # stream need several periods of folding.
    r0, v = 95.0, 5.0
    x = echo_samples(rc_schedule, r0, v, 0.9, snr_db=0.0, seed=4)
    est = _run(_receiver(rc_schedule), x)
    assert est and max(e.hop_index for e in est) > 3 * rc_schedule.period_hops
    dr, _ = _errors(est, r0, v)
    assert np.max(np.abs(dr)) < 0.1
    for e in est:
        assert e.t_s - e.t_tx_s == pytest.approx(2 * e.range_m / C)


def test_gap_restarts_accumulation_cleanly(rc_schedule: HopSchedule) -> None:
    r0, v = 50.0, 10.0
    x = echo_samples(rc_schedule, r0, v, 1.0, snr_db=0.0, seed=5)
    rx = _receiver(rc_schedule)
    gap = 20_000
    first = _run_no_flush(rx, x[:40_000])
    second = rx.process(x[40_000 + gap :], gap_before=gap) + rx.flush()
    assert rx.samples_seen == x.shape[0]
    t_gap_end = (40_000 + gap) / FS
    settle = (rx.lags.max() + rx.grid.lengths.max()) / rx.fs_bb
    assert all(e.t_s < 40_000 / FS for e in first)
    assert second and all(e.t_s > t_gap_end + settle - 0.002 for e in second)
    dr, _ = _errors(second, r0, v)
    assert np.max(np.abs(dr)) < 0.1
    assert np.all(np.diff([e.hop_index for e in second]) == 1)


def _run_no_flush(rx: GcasReceiver, x: np.ndarray) -> list[Estimate]:
    return rx.process(x)


def test_estimate_latency_is_within_one_hop(rc_schedule: HopSchedule) -> None:
    x = echo_samples(rc_schedule, 40.0, 10.0, 0.5, snr_db=0.0, seed=6)
    rx = _receiver(rc_schedule)
    block = 100
    for i in range(0, x.shape[0], block):
        for e in rx.process(x[i : i + block]):
            assert (i + block) / FS - e.t_s < rc_schedule.hop_s


@pytest.mark.parametrize(
    ("preset", "family", "search"),
    # tank-board's three-state cases take 0.5 s of CPU or more each: slow (the fast tier's rule).
    [pytest.param(*case, marks=pytest.mark.slow) if case[:2] == ("tank-board", "three-state")
     else case
     for case in itertools.product(["att", "tank-audio", "tank-board"],
                                   ["three-state", "random-cyclic"], ["two-stage", "full"])],
)  # fmt: skip
@pytest.mark.filterwarnings("error")
def test_every_preset_and_family(preset: str, family: str, search: str) -> None:
    # att three-state with the full search: its first detection's time was 2.75 grating lobes
    # (1.8 ms) late, and the refinement's lobe checks moved it by two lobes at most, leaving
    # a 0.51 m outlier; they move on while a neighbouring lobe is better (LOBE_MOVES).
    spec = get_preset(preset).spec(family)
    schedule = preset_schedule(preset, family)  # the two searches' receivers share its codewords
    c, vmax = spec.sound_speed_mps, spec.max_speed_mps
    r0, v = 0.6 * spec.max_range_m, 0.6 * vmax
    dur = 0.5 if preset != "tank-board" else 0.25
    m_hops = 8
    x = echo_samples(schedule, r0, v, dur, snr_db=0.0, seed=8, fs_hz=spec.fs_hz, c=c)
    rx = GcasReceiver.from_options(
        schedule, spec.fs_hz, sound_speed_mps=c, max_speed_mps=vmax,
        max_range_m=spec.max_range_m, m_hops=m_hops, n_doppler=32, search=search,
        reverb_speed_mps=0.0,  # 0.6 v_max is inside the tank presets' default band
    )  # fmt: skip
    est = _run(rx, x, block=int(spec.fs_hz // 10))
    assert len(est) >= 5
    rng_err = [e.range_m - (r0 - v * 0.5 * (e.t_s + e.t_tx_s)) for e in est]
    assert np.max(np.abs(rng_err)) < 0.05 * spec.max_range_m / 10
    assert abs(np.median([e.speed_mps for e in est]) - v) < 0.1 * vmax


@pytest.mark.slow
@pytest.mark.parametrize("speed", [20.0, -15.0])
def test_reverberation_band_excludes_stationary_clutter(
    rc_schedule: HopSchedule, speed: float
) -> None:
    # A stationary echo 6 dB above a moving target: without the band GCAS reports both at
    # every hop (the still echo as an echo at 0 m/s); with it (per tone in frequency) every
    # estimate is the target's, with no estimate near zero speed and none at a ghost speed
    # where α_d f_k = f_k'.
    r0 = 70.0
    clutter = echo_samples(rc_schedule, 35.0, 0.0, 0.6, amplitude=2.0)
    target = echo_samples(rc_schedule, r0, speed, 0.6, snr_db=0.0, seed=9)
    x = clutter + target
    plain = _run(_receiver(rc_schedule, reverb_speed_mps=0.0), x)
    still = sum(abs(e.speed_mps) < 0.5 for e in plain)
    moving = sum(abs(e.speed_mps - speed) < 0.5 for e in plain)
    assert still >= 45 and moving >= 45 and still + moving == len(plain)
    rx = _receiver(rc_schedule, reverb_speed_mps=5.0)
    every = _run(rx, x)
    # At most two (of 50) a ghost of the masked clutter, fitted well enough over runs of hops
    # (measured: beside the -15 m/s target one at 21.4 m/s, and one at 22.6 m/s that the
    # second search finds with the target taken out, hil.estimation.gcas.residual; none
    # beside the 20 m/s one).
    banded = [e for e in every if abs(e.speed_mps - speed) < 1.0]
    assert len(banded) >= 40 and len(every) - len(banded) <= 2
    dr, _ = _errors(banded, r0, speed)
    # The clutter's sidelobes and the masked cells cost accuracy (0.03 m rms without clutter).
    assert np.sqrt(np.mean(dr**2)) < 0.15 and np.max(np.abs(dr)) < 0.35
    # The band removes every cell whose frequency holds the clutter of some tone.
    assert rx.front_end.tone_w is not None and 0.3 < float(np.mean(rx.front_end.tone_w == 0)) < 0.6


def test_reverberation_tone_mask_covers_every_tones_zero_doppler_frequency(
    rc_schedule: HopSchedule,
) -> None:
    rx = _receiver(rc_schedule, reverb_speed_mps=5.0)
    assert rx.front_end.tone_w is not None
    f = rx.grid.alphas[:, None] * rx.tones_hz[None, :]
    for f_clutter in rc_schedule.tones_hz:
        # Every correlator listening within half a main lobe of a stationary tone is off.
        near = np.abs(f - f_clutter) < 0.5 / rc_schedule.hop_s
        assert near.any() and np.all(rx.front_end.tone_w[near] == 0)
    # A hypothesis far from every clutter frequency keeps all its tones.
    # (The band ±5 m/s is ±0.67 % of a tone, < 215 Hz, plus the 50 Hz guard.)
    far = np.all(np.abs(f[:, :, None] - rc_schedule.tones_hz).min(axis=2) > 300.0, axis=1)
    assert far.any() and np.all(rx.front_end.tone_w[far] == 1)


def test_time_codeword_map_and_full_accumulated_sum(rc_schedule: HopSchedule) -> None:
    seen: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    rx = _receiver(rc_schedule, on_map=lambda t, p, v: seen.append((t, p, v)))
    x = echo_samples(rc_schedule, 40.0, 12.0, 0.4, snr_db=0.0, seed=10)
    _run(rx, x)
    t = np.concatenate([s[0] for s in seen])
    p = np.concatenate([s[1] for s in seen])
    assert p.shape == (t.shape[0], rc_schedule.period_hops)
    times, full = rx.accumulated_sums(200)
    assert full.shape == (200, rx.grid.size, rc_schedule.period_hops)
    speeds = np.concatenate([s[2] for s in seen])[-200:]
    d_hat = np.searchsorted(rx.grid.speeds_mps, speeds)
    assert np.allclose(full[np.arange(200), d_hat], p[-200:], rtol=1e-5)
    assert np.allclose(times, t[-200:])


# ---------------------------------------------------------------------------- bad input
def test_nan_input_names_the_sample_index(rc_schedule: HopSchedule) -> None:
    rx = _receiver(rc_schedule)
    rx.process(np.zeros(1000))
    bad = np.zeros(500)
    bad[123] = np.nan
    with pytest.raises(ConfigError, match=r"block = 'nan at sample index 1123'.*finite"):
        rx.process(bad)


@pytest.mark.parametrize("m_hops", [2, 65])
def test_m_out_of_range_names_m_and_the_range(rc_schedule: HopSchedule, m_hops: int) -> None:
    with pytest.raises(ConfigError, match=rf"m_hops = {m_hops} .*an integer in 3\.\.64"):
        _receiver(rc_schedule, m_hops=m_hops)


def test_three_state_minimum_m_is_the_codeword_length() -> None:
    schedule = att_schedule("three-state")
    with pytest.raises(ConfigError, match=r"m_hops = 5 .*in 6\.\.64"):
        _receiver(schedule, m_hops=5)


def test_non_hfccw_schedule_is_refused() -> None:
    fmcw = check_design(get_preset("att").spec("fmcw-saw"))
    with pytest.raises(ConfigError, match=r"schedule.family = 'fmcw-saw' .*HFC-CW"):
        _receiver(fmcw)


def test_sample_rate_mismatch_is_refused(rc_schedule: HopSchedule) -> None:
    with pytest.raises(ConfigError, match=r"fs_hz = 96000.0 .*designed for, 100000 Hz"):
        GcasReceiver.from_options(
            rc_schedule, 96_000.0, sound_speed_mps=C, max_speed_mps=30.0, max_range_m=100.0,
            m_hops=10,
        )  # fmt: skip


def test_unknown_option_is_refused(rc_schedule: HopSchedule) -> None:
    with pytest.raises(ConfigError, match=r"receiver.options.bogus = 1 .* option of the gcas"):
        _receiver(rc_schedule, bogus=1)
