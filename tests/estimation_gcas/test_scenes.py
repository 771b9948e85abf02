"""GCAS in scenes beyond one target moving inside the span (att, M = 10, `max_speed_mps` 30 as
`hil estimate --max-speed 30`): a still or slow echo gives no ghost at the tone spacing's
speed, an echo faster than the span is not aliased, and a target inside the span is kept.

Before the refinement's coherence test a still echo at 40 m gave 0.41-0.79 false estimates
per hop at ±27-30 m/s and ranges anywhere; a 35 m/s target with a 30 m/s span gave estimates
at 7.3-8.0 m/s with wrong ranges. A ghost fits some hops of the schedule (a tone read as the
next one) but not their phases: its hops' coherence is far below one echo's.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from hil.estimation.base import Estimate
from hil.estimation.gcas import GcasReceiver
from sim_devices.acoustics.delay import TwoWayPath
from sim_devices.acoustics.echo import AnalyticEcho
from sim_devices.acoustics.trajectory import Fixed, Live
from sim_devices.acoustics.truth import HopTruth, hop_truth

from .conftest import FS, C, att_schedule, count_hits, echo_samples, run_blocks, true_range

SECONDS = 1.0
HOPS = SECONDS / 0.01


def _run(r0: float, v: float, snr_db: float, seed: int, max_speed: float = 30.0) -> list[Estimate]:
    schedule = att_schedule()
    x = echo_samples(schedule, r0, v, SECONDS, snr_db=snr_db, seed=seed)
    rx = GcasReceiver.from_options(
        schedule, FS, sound_speed_mps=C, max_speed_mps=max_speed, max_range_m=100.0, m_hops=10
    )
    return run_blocks(rx, x)


def _wrong(est: list[Estimate], r0: float, v: float) -> list[Estimate]:
    """Estimates more than 0.5 m or 0.5 m/s from the truth."""
    return [
        e
        for e in est
        if abs(e.speed_mps - v) > 0.5 or abs(e.range_m - true_range(r0, v, e.t_tx_s, e.t_s)) > 0.5
    ]


@pytest.mark.slow
@pytest.mark.parametrize("speed", [0.0, 0.05, 0.2])
def test_a_still_or_slow_echo_gives_no_ghost(speed: float) -> None:
    est = _run(40.0, speed, 0.0, seed=1)
    assert len(_wrong(est, 40.0, speed)) / HOPS <= 0.05


@pytest.mark.slow
@pytest.mark.parametrize("speed", [0.0, 0.05, 0.2])
def test_a_still_or_slow_echo_gives_no_ghost_at_minus_10_db(speed: float) -> None:
    # Measured: 1 wrong estimate in 100 hops at 0.05 m/s, none at 0 and 0.2.
    est = _run(40.0, speed, -10.0, seed=2)
    assert len(_wrong(est, 40.0, speed)) / HOPS <= 0.05


@pytest.mark.slow
def test_a_still_echo_with_the_span_at_the_design_speed_gives_no_ghost() -> None:
    est = _run(40.0, 0.0, 0.0, seed=3, max_speed=25.72)
    assert len(_wrong(est, 40.0, 0.0)) / HOPS <= 0.05


# At 0 dB the same run (input, seed and receiver) is test_an_echo_beyond_the_span_is_seen_once_
# on_its_side's closing case, which asserts at most 0.01 wrong estimates per hop of it.
@pytest.mark.parametrize("snr_db", [-10.0])
def test_a_target_faster_than_the_span_is_not_aliased(snr_db: float) -> None:
    est = _run(50.0, 35.0, snr_db, seed=4)
    assert len(_wrong(est, 50.0, 35.0)) / HOPS <= 0.05


def test_the_same_target_inside_a_wider_span_is_measured() -> None:
    est = _run(50.0, 35.0, 0.0, seed=4, max_speed=40.0)
    assert len(est) >= 60 and not _wrong(est, 50.0, 35.0)
    dr = np.array([e.range_m - true_range(50.0, 35.0, e.t_tx_s, e.t_s) for e in est])
    dv = np.array([e.speed_mps - 35.0 for e in est])
    assert np.sqrt(np.mean(dr**2)) < 0.005 and np.sqrt(np.mean(dv**2)) < 0.01


@pytest.mark.parametrize(("v", "snr_db"), [(12.0, -10.0), (-10.0, -10.0), (25.0, 0.0)])
def test_a_target_inside_the_span_keeps_every_boundary(v: float, snr_db: float) -> None:
    est = _run(70.0, v, snr_db, seed=5)
    good = [e for e in est if e not in _wrong(est, 70.0, v)]
    # One estimate per boundary once M hops are in: about 89 of 100 hops in 1 s.
    assert len(good) >= 85 and len(_wrong(est, 70.0, v)) == 0


@pytest.mark.parametrize(("r0", "v", "seed"), [(80.0, 27.0, 5), (60.0, 28.0, 8)])
def test_a_closing_target_beyond_the_design_speed_keeps_every_boundary_at_minus_10_db(
    r0: float, v: float, seed: int
) -> None:
    # Closing faster than the design speed (25.72 m/s), a boundary now and then brings no
    # detection (its row's maximum is the ghost's, a tone spacing away in the still band).
    # The echo is followed there, but its next boundary comes 9.6 ms later, before the
    # peaks decided have passed the missed one by a hop (FOLLOW_LAG_HOPS): the next
    # detection became the echo's latest fit and the missed boundary was never looked for
    # (an opening echo's boundaries come more than a hop apart). Measured: 86 / 84 of 92-93
    # boundaries before the gaps behind a fit were followed, 92 / 93 after; no wrong one.
    est = _run(r0, v, -10.0, seed=seed)
    wrong = _wrong(est, r0, v)
    assert len(est) - len(wrong) >= 91 and not wrong


def _braking(decel_mps2: float, m_hops: int = 10) -> tuple[list[Estimate], dict[int, HopTruth]]:
    """A target closing at 15 m/s from 60 m and braking at ``decel_mps2``, 0 dB, 1 s, read
    with ``m_hops`` hops."""
    schedule = att_schedule()

    def position(t: np.ndarray) -> np.ndarray:
        return np.stack([60.0 - 15.0 * t + 0.5 * decel_mps2 * t**2, 0 * t, 0 * t], axis=-1)

    def velocity(t: np.ndarray) -> np.ndarray:
        return np.stack([-15.0 + decel_mps2 * t, 0 * t, 0 * t], axis=-1)

    target = Live(position, velocity, max_speed_mps=20.0)
    path = TwoWayPath.monostatic(Fixed((0.0, 0.0, 0.0)), target, C)
    n = int(SECONDS * FS)
    x = AnalyticEcho(schedule, path, FS).block(0, n)
    x = x + np.random.default_rng(1).normal(0.0, np.sqrt(0.5), n)
    rx = GcasReceiver.from_options(
        schedule, FS, sound_speed_mps=C, max_speed_mps=30.0, max_range_m=100.0, m_hops=m_hops
    )
    truth = hop_truth(schedule, Fixed((0.0, 0.0, 0.0)), target, C, n / FS, 0.2)
    return run_blocks(rx, x), {h.hop_index: h for h in truth}


@pytest.mark.parametrize(("decel", "min_count"), [(2.0, 85), (7.0, 85), (12.0, 65)])
def test_a_braking_target_is_kept_and_ranged(decel: float, min_count: int) -> None:
    # The fit's time scale changes over the M hops where one speed leaves their phases
    # incoherent (hil.estimation.refine, accelerating echoes): speed and range are the
    # boundary's, without the mean speed's lag of decel * 0.05 m/s. Measured (seed 1, 91
    # boundaries): 2 m/s² 91 estimates, range RMSE 1.1 mm, speed bias +0.1 mm/s, RMS
    # 5.2 mm/s; 7 m/s² 90, 1.2 mm, -0.1 mm/s, 6.0 mm/s; 12 m/s² 70, 1.6 mm, +0.1 mm/s,
    # 8.7 mm/s (the constant-speed fits' coherence over runs of hops falls to 0.55-0.72
    # there: some are no longer tried).
    est, truth = _braking(decel)
    assert len(est) >= min_count
    dr = np.array([e.range_m - truth[e.hop_index + 1].range_m for e in est])
    dv = np.array([e.speed_mps - truth[e.hop_index + 1].radial_speed_mps for e in est])
    assert np.sqrt(np.mean(dr**2)) < 0.005
    assert abs(np.mean(dv)) < 0.005 and np.sqrt(np.mean(dv**2)) < 0.02


@pytest.mark.slow
def test_a_braking_target_over_a_long_window_is_read_at_its_boundary() -> None:
    # M = 29 at 4 m/s²: the curvature over the window is 10 rad at its ends, so the rates'
    # curves start from a constant-speed fit of the last 10 hops. Measured (seed 1): 40 of
    # 71 boundaries, range RMSE 0.3 mm, speed bias -0.1 mm/s, RMS 1.2 mm/s.
    est, truth = _braking(4.0, m_hops=29)
    assert len(est) >= 35
    dr = np.array([e.range_m - truth[e.hop_index + 1].range_m for e in est])
    dv = np.array([e.speed_mps - truth[e.hop_index + 1].radial_speed_mps for e in est])
    assert np.sqrt(np.mean(dr**2)) < 0.002
    assert abs(np.mean(dv)) < 0.002 and np.sqrt(np.mean(dv**2)) < 0.005


# Several echoes at once (issue 26 item 1): two targets at equal level apart, crossing in
# range, from the same range at different speeds, and a second one 10 dB weaker. Each
# target's detections count against the hop boundaries it gives alone.
TWO_TARGETS = {
    "apart": ((45.0, 10.0, 1.0), (60.0, -6.0, 1.0)),
    "crossing": ((50.0, 10.0, 1.0), (40.0, -5.0, 1.0)),
    "same start": ((50.0, 8.0, 1.0), (50.0, 16.0, 1.0)),
    "10 dB weaker": ((45.0, 10.0, 1.0), (60.0, -6.0, 0.316)),
    # One speed (a formation): the two rows' boundaries 0.4 and 0.35 hop apart, and one hop
    # of delay apart (every boundary of one arrives with one of the other). Measured (seed
    # 11): 0.993 / 0.986, 1.0 / 1.0 and 1.0 / 1.0 at 0 and -10 dB (3, 10.1 and 7.5 m); no
    # false estimate (0.01-0.54 per target before the rows' second maxima, the refinement's
    # partners and the tied codewords' reading; the 7.5 m pair 0.922 / 1.0 while a boundary
    # missed just before the echo's next detection was not followed, CoherentRefiner.due).
    # A tone spacing's speed apart (26 of 27.5 m/s on att): each one's tones are read as the
    # other's neighbours, and the boundaries of each pass where the other's ghost peaks half
    # of the time (the two delays slip one hop in 0.29 s). Measured (seed 11): 1.0 / 0.979
    # at 0 dB and 1.0 / 0.993 at -10 dB, no false estimate; 0.50 / 0.47 and 0.50 / 0.45 when
    # every detection there no stronger than the measured echo was taken for its ghost
    # (CoherentRefiner.ghost_of_known, GHOST_FRACTION).
    "a tone spacing's speed apart": ((45.0, -6.0, 1.0), (85.0, 20.0, 1.0)),
    # The second 4, 5 and 6 dB weaker (27.5 m/s apart: its boundaries pass where the
    # stronger one's ghost peaks). Read with the stronger echo taken out, a ghost keeps a few
    # per cent of it and the weaker echo its own level (refine.GHOST_LEFT); once fitted, the
    # weaker one is followed through the ghost's hops: where its peak is only the second of
    # its row, and where the ghost's peak hides it, at the boundary its fit puts next
    # (Readout._follow), also where its next detection came first (CoherentRefiner.due).
    # Measured (seed 11, 0 / -10 dB): 4 dB 1.0 / 1.0, 5 dB 1.0 / 1.0, 6 dB 0.993 / 0.874, no
    # false estimate (5 dB 0.951 / 0.93 and 6 dB 0.888 / 0.713 before those boundaries were
    # followed); 0.66 / 0.50, 0.18 / 0.16 and 0.105 / 0.112 when every detection there
    # reading at most 0.6 of the echo with it in, or as weak as its strongest ghost, was
    # that ghost; 0.993 / 1.0, 0.867 / 0.734 and 0.538 / 0.476 without following.
    "a tone spacing's speed apart, 4 dB weaker": ((50.0, 10.0, 1.0), (70.0, -17.5, 0.63)),
    "a tone spacing's speed apart, 5 dB weaker": ((60.0, -8.0, 1.0), (45.0, 19.5, 0.56)),
    "a tone spacing's speed apart, 6 dB weaker": ((60.0, -8.0, 1.0), (45.0, 19.5, 0.5)),
    # Nearby speeds (2-2.3 m/s apart, within a Doppler cell of a hop, 2.5 m/s on att): each
    # one's row holds the other's Doppler response, so the weaker one's boundary is only a
    # second maximum of its row (refine.NEIGHBOUR_CELLS). Measured (seed 11): 0.993 / 1.0
    # and 0.993 / 1.0 at 0 dB, 0.993 / 0.993 and 0.993 / 0.986 at -10 dB, no false estimate;
    # 0.48 / 0.48 and 0.89 / 0.08 at 0 dB when they were decided beside echoes of their own
    # speed only.
    "2.3 m/s apart": ((80.0, 15.1, 1.0), (68.0, 12.8, 1.0)),
    "2 m/s apart": ((80.0, 15.0, 1.0), (68.0, 13.0, 1.0)),
    # The second 5 dB weaker and 3.4 / 3.9 m/s (1.4 / 1.6 Doppler cells of a hop) from the
    # first: the first's main lobe holds every cell of stage 1 within a cell of the weaker
    # one's, whose boundary is a peak of its own only over ±1 hypothesis
    # (kernels.masked_peak_cells), decided beside the measured first (Peak.masked). See
    # test_a_weaker_target_a_doppler_cell_or_so_from_a_stronger_one for the figures.
    "3.4 m/s apart, 5 dB weaker": ((36.0, -19.0, 1.0), (21.0, -15.6, 0.562)),
    "3.9 m/s apart, 5 dB weaker": ((73.0, 15.5, 1.0), (50.0, 19.4, 0.562)),
    # The second 10 dB weaker in the first's Doppler row (one speed, 20 m apart), a Doppler
    # cell of a hop from it (2.6 m/s) or beside its ghost's row (29.4 m/s apart, 2 m/s from
    # a tone spacing's speed): it is no maximum of its own in the input (the first's row
    # falls over a hop from its boundary, several times steeper than the weaker one's own
    # peak), and is found in the input with the first taken out
    # (hil.estimation.gcas.residual). See test_a_target_10_db_weaker_in_a_stronger_ones_row.
    "10 dB weaker, one speed": ((70.0, 12.0, 1.0), (50.0, 12.0, 0.316)),
    "10 dB weaker, 2.6 m/s apart": ((70.0, 12.0, 1.0), (50.0, 9.4, 0.316)),
    "10 dB weaker, beside a ghost's row": ((78.0, 23.6, 1.0), (82.0, -5.8, 0.316)),
    "one speed, 3 m apart": ((50.0, 10.0, 1.0), (53.0, 10.0, 1.0)),
    "one speed, 10.1 m apart": ((50.0, 10.0, 1.0), (60.1, 10.0, 1.0)),
    # One hop of delay apart: every boundary of one arrives with a boundary of the other.
    "one speed, 7.5 m apart": ((50.0, 10.0, 1.0), (57.5, 10.0, 1.0)),
}
SCENE_S = 1.5


def _scene(
    targets: tuple[tuple[float, float, float], ...], snr_db: float, **options: object
) -> list[Estimate]:
    """GCAS's estimates over :data:`SCENE_S` of ``targets`` (range m, closing speed m/s,
    amplitude each) in white noise of per-sample SNR ``snr_db`` (seed 11), read with receiver
    ``options``. Each scene is read once per process: a target alone is the reference of
    several pairs (50 m at 10 m/s of eight at each SNR), and its estimates are the same every
    time (the synthesis, the noise and the receiver are deterministic)."""
    return list(_scene_once(targets, snr_db, tuple(sorted(options.items()))))


@functools.cache
def _scene_once(
    targets: tuple[tuple[float, float, float], ...],
    snr_db: float,
    options: tuple[tuple[str, object], ...],
) -> tuple[Estimate, ...]:
    """:func:`_scene`'s estimates, frozen (shared by every test that reads them)."""
    schedule = att_schedule()
    x = sum(echo_samples(schedule, r, v, SCENE_S, amplitude=a) for r, v, a in targets)
    sigma = 1.0 / np.sqrt(2.0) / 10 ** (snr_db / 20.0)
    x = x + np.random.default_rng(11).normal(0.0, sigma, np.shape(x))
    rx = GcasReceiver.from_options(
        schedule, FS, sound_speed_mps=C, max_speed_mps=30.0, max_range_m=100.0, m_hops=10,
        **dict(options),
    )  # fmt: skip
    return tuple(run_blocks(rx, x))


def _detection_and_false(
    scene: str, snr_db: float, targets: tuple[tuple[float, float, float], ...] = (),
    **options: object,
) -> tuple[list[float], float]:  # fmt: skip
    targets = targets or TWO_TARGETS[scene]
    est = _scene(targets, snr_db, **options)
    alone = [count_hits(_scene((t,), snr_db, **options), t[0], t[1]) for t in targets]
    hits = [count_hits(est, t[0], t[1]) for t in targets]
    false = len(est) - sum(hits)
    return [h / a for h, a in zip(hits, alone, strict=True)], false / (SCENE_S / 0.01)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("scene", "pd_min"),
    # 0.8-1.1 CPU s each: the fast tier keeps one of each kind, --all runs every one.
    [("apart", 0.99), ("one speed, 3 m apart", 0.98),
     *(pytest.param(*case, marks=pytest.mark.slow) for case in
       (("crossing", 0.99), ("same start", 0.99), ("10 dB weaker", 0.95),
        ("a tone spacing's speed apart", 0.95), ("a tone spacing's speed apart, 4 dB weaker", 0.95),
        ("a tone spacing's speed apart, 5 dB weaker", 0.98),
        ("a tone spacing's speed apart, 6 dB weaker", 0.97), ("2.3 m/s apart", 0.98),
        ("2 m/s apart", 0.98),
        ("one speed, 10.1 m apart", 0.98), ("one speed, 7.5 m apart", 0.98)))],
)  # fmt: skip
def test_every_target_at_every_hop_at_0_db(scene: str, pd_min: float) -> None:
    # Measured: 1.0 / 1.0 for the equal pairs and for the weaker one, here and with another
    # noise seed (the stronger one's ghosts and sidelobes are taken out; beside it a
    # detection up to a grating lobe and a half off is searched over three lobes); no
    # false estimate.
    pd, false = _detection_and_false(scene, 0.0)
    assert min(pd) >= pd_min and max(pd) <= 1.0
    assert false <= 0.01


@pytest.mark.slow
@pytest.mark.parametrize(
    "scene",
    ["apart", "crossing", "same start", "a tone spacing's speed apart", "2.3 m/s apart",
     "2 m/s apart", "one speed, 3 m apart", "one speed, 10.1 m apart", "one speed, 7.5 m apart"],
)  # fmt: skip
def test_two_equal_targets_at_every_hop_at_minus_10_db(scene: str) -> None:
    pd, false = _detection_and_false(scene, -10.0)
    assert min(pd) >= 0.95 and false <= 0.02


@pytest.mark.slow
@pytest.mark.parametrize(
    ("scene", "pd_min"),
    [("a tone spacing's speed apart, 4 dB weaker", 0.95),
     ("a tone spacing's speed apart, 5 dB weaker", 0.95),
     ("a tone spacing's speed apart, 6 dB weaker", 0.8)],
)  # fmt: skip
def test_a_weaker_target_where_a_stronger_ones_ghost_peaks_at_minus_10_db(
    scene: str, pd_min: float
) -> None:
    pd, false = _detection_and_false(scene, -10.0)
    assert min(pd) >= pd_min and false <= 0.02


@pytest.mark.slow
@pytest.mark.parametrize(
    ("scene", "snr_db", "pd_min"),
    [("3.4 m/s apart, 5 dB weaker", 0.0, 0.95), ("3.4 m/s apart, 5 dB weaker", -10.0, 0.95),
     ("3.9 m/s apart, 5 dB weaker", 0.0, 0.95), ("3.9 m/s apart, 5 dB weaker", -10.0, 0.95)],
)  # fmt: skip
def test_a_weaker_target_a_doppler_cell_or_so_from_a_stronger_one(
    scene: str, snr_db: float, pd_min: float
) -> None:
    # Measured (seed 11), the weaker one: 3.4 m/s 0.985 / 1.0 at 0 / -10 dB, 3.9 m/s 1.0 /
    # 0.993; the stronger 1.0; no false estimate. 0.456 / 0.853 and 0.754 / 0.648 while a
    # boundary missed just before the echo's next detection was not followed
    # (CoherentRefiner.due); 0.0 / 0.0 and 0.254 / 0.648 while a cell masked by a greater
    # one within the lobe was no candidate.
    pd, false = _detection_and_false(scene, snr_db)
    assert pd[0] >= 0.99 and pd_min <= pd[1] <= 1.0
    assert false <= 0.01


@pytest.mark.slow
@pytest.mark.parametrize(
    ("scene", "snr_db", "pd_min"),
    [("10 dB weaker, one speed", 0.0, 0.95), ("10 dB weaker, 2.6 m/s apart", 0.0, 0.95),
     ("10 dB weaker, beside a ghost's row", 0.0, 0.95),
     ("10 dB weaker, one speed", -10.0, 0.9), ("10 dB weaker, 2.6 m/s apart", -10.0, 0.9),
     ("10 dB weaker, beside a ghost's row", -10.0, 0.9)],
)  # fmt: skip
def test_a_target_10_db_weaker_in_a_stronger_ones_row(
    scene: str, snr_db: float, pd_min: float
) -> None:
    # Measured (seed 11), the weaker one (at -10 / -20 dB per-sample SNR): 1.0 / 0.921 at
    # one speed (0.866 before the boundaries missed just before its next detection were
    # followed), 1.0 / 0.966 2.6 m/s apart, 1.0 (1.5 of its boundaries alone) / 0.991 beside
    # the ghost's row; the stronger 1.0; at most 0.013 false per hop. With one search
    # (cancel=False): 0.0 at 0 dB in the first two, 0.0-0.04 (independent synthesis).
    pd, false = _detection_and_false(scene, snr_db)
    assert pd[0] >= 0.99 and pd[1] >= pd_min
    assert false <= 0.02


# Two echoes of one speed close in range (hil.estimation.refine_pair): they share the
# detector's peak and every hop; the one-echo fit of them is refused (their tones' phases
# disagree) or, a grating lobe apart (0.68 m on att), passes on either by turns. Closer than
# the main lobe 1/B (0.23 m) they are one resolution cell and one estimate is reported.
CLOSE_PAIRS = {
    "0.3 m apart": ((50.0, 10.0, 1.0), (50.3, 10.0, 1.0)),
    "a grating lobe apart": ((50.0, 10.0, 1.0), (50.7, 10.0, 1.0)),
    "1.5 m apart": ((50.0, 10.0, 1.0), (51.5, 10.0, 1.0)),
    "opening, 0.5 m apart": ((60.0, -8.0, 1.0), (60.5, -8.0, 1.0)),
}


def _close_pair(targets: tuple[tuple[float, float, float], ...], snr_db: float) -> tuple[
    list[float], float, int
]:  # fmt: skip
    """Each target's detected boundaries (an estimate within half the pair's separation of
    its range, and 0.5 m/s of its speed) over those it gives alone, false estimates per hop,
    and the most estimates at the pair's speed at one boundary."""
    gate = 0.5 * abs(targets[1][0] - targets[0][0])

    def hits(est: list[Estimate], r0: float, v: float) -> int:
        return sum(
            abs(e.speed_mps - v) < 0.5
            and abs(e.range_m - true_range(r0, v, e.t_tx_s, e.t_s)) < gate
            for e in est
        )

    est = _scene(targets, snr_db)
    alone = [hits(_scene((t,), snr_db), t[0], t[1]) for t in targets]
    got = [hits(est, t[0], t[1]) for t in targets]
    hops = [e.hop_index for e in est if abs(e.speed_mps - targets[0][1]) < 0.5]
    per_hop = np.bincount(np.asarray(hops) - min(hops))
    false = (len(est) - sum(got)) / (SCENE_S / 0.01)
    return [h / a for h, a in zip(got, alone, strict=True)], false, int(per_hop.max())


@pytest.mark.slow
@pytest.mark.parametrize(
    ("scene", "snr_db", "pd_min"),
    [("0.3 m apart", 0.0, 0.95), ("0.3 m apart", -10.0, 0.95),
     ("a grating lobe apart", 0.0, 0.9), ("a grating lobe apart", -10.0, 0.9),
     ("1.5 m apart", 0.0, 0.95), ("1.5 m apart", -10.0, 0.95),
     ("opening, 0.5 m apart", 0.0, 0.94), ("opening, 0.5 m apart", -10.0, 0.94)],
)  # fmt: skip
def test_two_echoes_of_one_speed_close_in_range_are_both_reported(
    scene: str, snr_db: float, pd_min: float
) -> None:
    # Measured (seed 11, 0 / -10 dB): 0.3 m 0.957 / 0.957 each at both; a grating lobe
    # 0.993 / 0.922 and 0.922 / 0.936; 1.5 m 0.986 / 0.965 and 0.986 / 0.957; opening 0.5 m
    # 0.949 each at both; at most 0.007 false per hop (before, on an independent synthesis
    # at 0 dB: 0.0 / 0.0, 0.40 / 0.58, 0.80 / 0.79 and 0.0 / 0.0). Lost: the first M - 1
    # boundaries, whose windows begin before the transmission (no new pair is tried there),
    # and a grating lobe apart the boundaries before the one-echo fit first jumps from one
    # echo to the other.
    pd, false, most = _close_pair(CLOSE_PAIRS[scene], snr_db)
    assert min(pd) >= pd_min and max(pd) <= 1.0
    assert false <= 0.02 and most == 2


def test_two_echoes_within_one_resolution_cell_are_one_estimate() -> None:
    # 0.15 m apart (0.20 ms, below 1/B = 0.30 ms): one estimate a boundary, between them.
    # Measured (seed 11, 0 dB): 141 estimates, within 3 mm of the midpoint.
    targets = ((50.0, 10.0, 1.0), (50.15, 10.0, 1.0))
    est = _scene(targets, 0.0)
    per_hop = np.bincount([e.hop_index - min(e.hop_index for e in est) for e in est])
    assert per_hop.max() == 1
    mid = [true_range(50.075, 10.0, e.t_tx_s, e.t_s) for e in est]
    assert max(abs(e.range_m - m) for e, m in zip(est, mid, strict=True)) < 0.1


@pytest.mark.slow
def test_one_search_misses_a_target_10_db_weaker_in_a_stronger_ones_row() -> None:
    # The same scene without the second search: the weaker one is not found.
    pd, _ = _detection_and_false("10 dB weaker, one speed", 0.0, cancel=False)
    assert pd[0] >= 0.99 and pd[1] <= 0.1


def _receiver(max_speed: float = 30.0, **extra: object) -> GcasReceiver:
    return GcasReceiver.from_options(
        att_schedule(), FS, sound_speed_mps=C, max_speed_mps=max_speed, max_range_m=100.0,
        m_hops=10, **extra,
    )  # fmt: skip


@pytest.mark.parametrize(
    ("v", "side"), [(35.0, "closing"), pytest.param(-35.0, "opening", marks=pytest.mark.slow)]
)
def test_an_echo_beyond_the_span_is_seen_once_on_its_side(v: float, side: str) -> None:
    # Its edge leak on the span's edge hypothesis, scanned over the guard band, fits one
    # echo at its own speed, said at the second fit of hops all transmitted: measured
    # 34.999 / -35.001 m/s at hop 9; then it is fitted again at each edge detection and at
    # its ghosts (151 / 154 refused as its) and its ghosts are taken out: no estimate.
    x = echo_samples(att_schedule(), 50.0, v, SECONDS, snr_db=0.0, seed=4)
    rx = _receiver()
    est = run_blocks(rx, x)
    assert len(_wrong(est, 50.0, v)) / HOPS <= 0.01 and rx.beyond_span_count >= 50
    assert [s.side for s in rx.beyond_span] == [side]
    seen = rx.beyond_span[0]
    assert seen.hop_index <= 12 and seen.max_speed_mps == 30.0
    assert seen.speed_mps == pytest.approx(v, abs=0.1)
    rx.reset()
    assert rx.beyond_span == [] and rx.beyond_span_count == 0


@pytest.mark.slow
@pytest.mark.parametrize(
    ("r0", "v", "side", "said_hop", "said_mps", "refused"),
    [(80.0, 35.0, "closing", 9, 34.993, 158), (20.0, -35.0, "opening", 9, -35.005, 165)],
)
def test_an_echo_beyond_the_span_is_said_from_its_ghosts_at_minus_10_db(
    r0: float, v: float, side: str, said_hop: int, said_mps: float, refused: int
) -> None:
    """2 s, 200 hops; ``refused``: the detections refused as that echo's, measured."""
    # At -10 dB the echo's leak on the edge hypothesis is seldom detected, its ghosts one and
    # two tone spacings inward are (+-7.5 and -+20 m/s): the source each puts beyond the span
    # is fitted there, said at its second fit from hop M - 1 on, and the ghosts are refused
    # as its (the figures asserted are the measured ones), those that pass the echo test
    # included.
    x = echo_samples(att_schedule(), r0, v, 2.0, snr_db=-10.0, seed=4)
    rx = _receiver()
    est = run_blocks(rx, x)
    assert _wrong(est, r0, v) == [] and abs(rx.beyond_span_count - refused) <= 10
    assert [s.side for s in rx.beyond_span] == [side]
    seen = rx.beyond_span[0]
    assert seen.hop_index == said_hop and seen.speed_mps == pytest.approx(said_mps, abs=1e-3)
    assert abs(seen.speed_mps - v) <= 0.1


@pytest.mark.parametrize(
    ("r0", "v", "max_speed", "said_hop", "said_mps", "refused"),
    [
        *(
            pytest.param(*case, marks=pytest.mark.slow)
            for case in (
                (90.0, 40.0, 30.0, 11, 40.003, 154),
                (5.0, -40.0, 30.0, 14, -40.002, 155),
                (90.0, 45.0, 30.0, 9, 44.998, 157),
                (5.0, -45.0, 30.0, 11, -44.998, 159),
            )
        ),
        (95.0, 55.0, 30.0, 12, 55.001, 101),
        pytest.param(90.0, 35.0, 20.0, 13, 34.999, 118, marks=pytest.mark.slow),
    ],
)
def test_an_echo_past_the_guard_band_is_said_from_its_ghosts_at_minus_10_db(
    r0: float, v: float, max_speed: float, said_hop: int, said_mps: float, refused: int
) -> None:
    """2 s, 200 hops (55 m/s: 1.5 s); ``refused``: the detections refused as that echo's,
    measured."""
    # Past the guard band (7.5 m/s past the edge) nothing of the echo reaches the edge
    # hypothesis: its ghosts one, two or three tone spacings inward are all there is (40 m/s:
    # 12.5 and -15 m/s; 45 m/s: 17.5 and -10 m/s; 55 m/s: 27.5 and -27.5 m/s, the one
    # between in the reverberation band; 35 m/s with a 20 m/s span: 7.5 and -20 m/s). The
    # source each puts beyond the span is scanned for over a code period's hops and fitted,
    # said once at its own speed, and its ghosts are refused as its.
    seconds = 1.5 if abs(v) > 50.0 else 2.0
    x = echo_samples(att_schedule(), r0, v, seconds, snr_db=-10.0, seed=4)
    rx = _receiver(max_speed)
    est = run_blocks(rx, x)
    assert len(_wrong(est, r0, v)) / (seconds / 0.01) <= 0.01
    assert abs(rx.beyond_span_count - refused) <= 10
    [seen] = rx.beyond_span
    assert seen.side == ("closing" if v > 0 else "opening") and seen.max_speed_mps == max_speed
    assert seen.hop_index == said_hop and seen.speed_mps == pytest.approx(said_mps, abs=1e-3)
    assert abs(seen.speed_mps - v) <= 0.1


@pytest.mark.parametrize(
    ("v", "snr_db"),
    [(25.0, 0.0), (29.8, 0.0), (-29.8, -10.0), (29.8, -10.0), (25.0, -10.0), (-25.0, -10.0)],
)
def test_a_target_inside_the_span_near_its_edge_is_not_taken_for_one_beyond(
    v: float, snr_db: float
) -> None:
    est = run_blocks(rx := _receiver(), echo_samples(att_schedule(), 50.0, v, SECONDS,
                                                     snr_db=snr_db, seed=6))  # fmt: skip
    assert rx.beyond_span == [] and rx.beyond_span_count == 0
    # Measured: no wrong estimate at 25 and -29.8 m/s, one at 29.8 m/s (-29.4 m/s at 9.7 m),
    # at 0 dB; none at -10 dB (85-92 estimates).
    assert len(est) >= 85 and len(_wrong(est, 50.0, v)) / HOPS <= 0.02


@pytest.mark.slow
def test_the_design_speed_reads_without_bias_with_the_band_on() -> None:
    # +25 m/s on att sits beside the Doppler cells the band masks as another tone's clutter
    # (26.5 ± 1.3 m/s for the third tone read as the fourth): the detector's own speed is
    # pulled 0.34 m/s low there; the refinement measures the echo itself (measured bias
    # -0.0001 m/s at 0 dB, -0.0000 at -10 dB).
    for snr_db in (0.0, -10.0):
        x = echo_samples(att_schedule(), 70.0, 25.0, 1.5, snr_db=snr_db, seed=5)
        est = run_blocks(_receiver(), x)
        dv = np.array([e.speed_mps - 25.0 for e in est])
        assert len(est) >= 130 and abs(np.mean(dv)) <= 0.01 and np.max(np.abs(dv)) < 0.05


@pytest.mark.parametrize(("snr_db", "bias_max"), [(0.0, 0.04), (-10.0, 0.02)])
def test_the_detector_alone_reads_the_design_speed_without_bias(
    snr_db: float, bias_max: float
) -> None:
    # Without refinement the speed is the parabola through the codeword sums of three
    # hypotheses; beside the masked ghost cells it is measured on the tones all three hold
    # and centred on the largest (measured bias +0.025 m/s at 0 dB, -0.002 at -10 dB; it
    # read -0.336 and -0.344 on sums of unequal tones).
    x = echo_samples(att_schedule(), 70.0, 25.0, 1.5, snr_db=snr_db, seed=5)
    est = run_blocks(_receiver(refine=False), x)
    dv = np.array([e.speed_mps - 25.0 for e in est])
    assert len(est) >= 140 and abs(np.mean(dv)) <= bias_max


# Still, stopping and reversing echoes (issue 26 item 3) at 0 and -10 dB, with and without
# volume reverberation at 0 dB SRR (a stationary omni sonar: the reverberation sits at zero
# Doppler around every tone), the band on (the default), 2 s.
MOTION_S = 2.0
MOTION_HOPS = MOTION_S / 0.01


def _motion_scene(
    kind: str, snr_db: float, srr_db: float | None, seed: int = 3
) -> tuple[list[Estimate], dict[int, HopTruth]]:
    """``kind``: "still" (40 m at rest), "slow" (from 40 m closing at 0.5 m/s), "braking"
    (from 50 m closing at 10 m/s, 5 m/s² to rest at 2 s) or "reversing" (from 50 m, +8 m/s
    closing to -8 m/s opening at 8 m/s²)."""
    x, truth = _motion_input(kind, snr_db, srr_db, seed)
    return run_blocks(_receiver(), x), truth


def _motion_input(
    kind: str,
    snr_db: float,
    srr_db: float | None,
    seed: int,
    *,
    min_range_m: float = 5.0,
    density_per_m3: float = 0.01,
) -> tuple[np.ndarray, dict[int, HopTruth]]:
    """The input of :func:`_motion_scene` (shape ``(n,)``) and its truth per hop boundary;
    the reverberation's scatterers (``density_per_m3``) from ``min_range_m`` to 100 m."""
    r0, v0, acc = {"still": (40.0, 0.0, 0.0), "slow": (40.0, 0.5, 0.0),
                   "braking": (50.0, 10.0, 5.0), "reversing": (50.0, 8.0, 8.0)}[kind]  # fmt: skip

    def position(t: np.ndarray) -> np.ndarray:
        return np.stack([r0 - v0 * t + 0.5 * acc * t**2, 0 * t, 0 * t], axis=-1)

    def velocity(t: np.ndarray) -> np.ndarray:
        return np.stack([-v0 + acc * t, 0 * t, 0 * t], axis=-1)

    schedule, sonar = att_schedule(), Fixed((0.0, 0.0, 0.0))
    target = Live(position, velocity, max_speed_mps=20.0)
    n = int(MOTION_S * FS)
    x = AnalyticEcho(schedule, TwoWayPath.monostatic(sonar, target, C), FS).block(0, n)
    x = x + np.random.default_rng(seed).normal(0.0, np.sqrt(0.5) / 10 ** (snr_db / 20.0), n)
    if srr_db is not None:
        reverb, power = _reverberation(seed + 100, min_range_m, density_per_m3)
        scale = np.sqrt(0.5 / (10 ** (srr_db / 10.0) * power))
        x = x + scale * reverb
    truth = {h.hop_index: h for h in hop_truth(schedule, sonar, target, C, MOTION_S, 0.2)}
    return x, truth


@functools.cache
def _reverberation(
    seed: int, min_range_m: float, density_per_m3: float
) -> tuple[np.ndarray, float]:
    """:func:`_motion_input`'s volume reverberation around the still omni sonar (scatterers
    from ``min_range_m`` to 100 m, seeded ``seed``), shape ``(MOTION_S·FS,)``, read-only, and
    its expected power at t = 0 (µPa²). Made once per process: at 0.3 scatterers/m³ it costs
    about 1.5 s of CPU, and several modules' tests read the same scene (test_still_codewords,
    test_chunks_in_reverberation, tests/cli's near water)."""
    from sim_devices.acoustics.beam import OmniBeam, TwoWayAmplitudeTable
    from sim_devices.acoustics.reverberation import ReverberationSettings, VolumeReverberation

    settings = ReverberationSettings(
        density_per_m3=density_per_m3, scattering_strength_db=-70.0, max_range_m=100.0,
        min_range_m=min_range_m, seed=seed,
    )  # fmt: skip
    rev = VolumeReverberation(
        att_schedule(), FS, source_amplitude_upa=1.0, reference_hz=30e3,
        sonar_position_m=(0.0, 0.0, 0.0), sonar_velocity_mps=(0.0, 0.0, 0.0),
        beam=TwoWayAmplitudeTable(OmniBeam(), OmniBeam()), beam_axis=(1.0, 0.0, 0.0),
        sound_speed_mps=C, settings=settings,
    )  # fmt: skip
    power = rev.expected_power(0.0)
    reverb = rev.generate(int(MOTION_S * FS))
    reverb.flags.writeable = False
    return reverb, power


def _false_and_moving_pd(
    est: list[Estimate], truth: dict[int, HopTruth], faster_than_mps: float = 4.0
) -> tuple[float, float]:
    """False estimates per hop (more than 0.5 m or 0.5 m/s from the truth of their boundary)
    and the detected fraction of the boundaries faster than ``faster_than_mps`` (default
    4 m/s: outside the band; below 0: every boundary)."""
    on_target = [
        (h := truth.get(e.hop_index + 1)) is not None
        and abs(e.range_m - h.range_m) < 0.5
        and abs(e.speed_mps - h.radial_speed_mps) < 0.5
        for e in est
    ]
    hit = {e.hop_index + 1 for e, ok in zip(est, on_target, strict=True) if ok}
    false = on_target.count(False) / MOTION_HOPS
    scored = [k for k, h in truth.items() if 0.13 < h.t_rx_s < MOTION_S - 0.03]
    moving = [k for k in scored if abs(truth[k].radial_speed_mps) > faster_than_mps]
    return false, sum(k in hit for k in moving) / max(len(moving), 1)


@pytest.mark.slow
def test_a_target_braking_to_rest_gives_no_false_estimate() -> None:
    # Measured: 2 false estimates in 200 hops (30.1 m/s at 31.8 m, 24.4 m/s at 36.8 m),
    # every moving boundary detected (111 of them), none once it is slower than the band.
    false, pd = _false_and_moving_pd(*_motion_scene("braking", 0.0, None))
    assert false <= 0.015 and pd >= 0.99


@pytest.mark.slow
@pytest.mark.parametrize(
    ("kind", "snr_db", "srr_db", "pd_min", "false_max"),
    # Measured false per hop / moving pd: still 0 / -, 0.005 / -, 0.005 / -, 0.005 / -;
    # braking (0 dB, reverberation) 0 / 1.0, (-10 dB) 0.005 / 1.0, (-10 dB, reverberation)
    # 0.005 / 1.0; reversing 0.005 / 0.964, 0 / 0.964, 0 / 0.976, 0 / 0.976. The fit's time
    # scale follows the 8 m/s² turn (hil.estimation.refine, accelerating echoes); what is
    # missed is the detector's: near the band's edge (3.0-3.4 m/s closing, 3.0-4.2 m/s
    # opening, where its mean speed over the window lags the boundary's) it peaks on the band's
    # edge hypothesis, refused. In reverberation the target was also refused as the ghost of
    # its own ghost beyond the span (a weak fit at -32.5 m/s that passed the echo test first):
    # a ghost is weaker than its echo (CoherentRefiner.ghost_of_known), 0.917 / 0.929 before.
    # Still at -10 dB in reverberation: 0.025 before a fit where the target's fit at rest
    # leaks, that fit taken out, had to collect the follow gate (the detection is the leak,
    # and its fit read the noise and reverberation there; docs/receiver.md, "A still wall far
    # above a target").
    [
        ("still", 0.0, None, 0.0, 0.015), ("still", -10.0, None, 0.0, 0.015),
        ("still", 0.0, 0.0, 0.0, 0.015), ("still", -10.0, 0.0, 0.0, 0.015),
        ("braking", 0.0, 0.0, 0.99, 0.015), ("braking", -10.0, None, 0.99, 0.015),
        ("braking", -10.0, 0.0, 0.99, 0.015), ("reversing", 0.0, None, 0.95, 0.015),
        ("reversing", 0.0, 0.0, 0.95, 0.015), ("reversing", -10.0, None, 0.95, 0.015),
        ("reversing", -10.0, 0.0, 0.95, 0.015),
    ],
)  # fmt: skip
def test_still_stopping_and_reversing_echoes_give_no_false_estimate(
    kind: str, snr_db: float, srr_db: float | None, pd_min: float, false_max: float
) -> None:
    false, pd = _false_and_moving_pd(*_motion_scene(kind, snr_db, srr_db))
    assert false <= false_max and pd >= pd_min


@pytest.mark.slow
@pytest.mark.parametrize(("max_speed", "snr_db"), [(25.72, 0.0), (25.72, -10.0), (30.0, -10.0)])
def test_a_still_target_gives_few_ghosts_at_the_design_speed_span(
    max_speed: float, snr_db: float
) -> None:
    # att's design speed (--max-speed 25.72) puts the span 1.8 m/s short of a still echo's
    # ghost one tone spacing out (27.5 m/s); its tail is fitted inside at 24.0-25.4 m/s on a
    # few boundaries at -10 dB. A still target at 40 m, no reverberation, the default band,
    # three 2 s seeds. Measured false per hop (six seeds): 25.72 m/s 0 at 0 dB, 0.023 at
    # -10 dB (0-0.04 per seed); 30 m/s at -10 dB 0.006.
    s = att_schedule()
    false = 0
    for seed in range(3):
        x = echo_samples(s, 40.0, 0.0, 2.0, snr_db=snr_db, seed=1000 + seed)
        false += len(run_blocks(_receiver(max_speed), x))
    per_hop = false / (3 * 2.0 / s.hop_s)
    assert per_hop <= (0.0 if snr_db == 0.0 else 0.05)


# The band off (the documented setting for a slow or still target) in volume reverberation at
# 0 dB SRR whose scatterers start 1 m from the sonar: the reverberation sits at the tones, so
# a still target's hops hold more of it than the white-noise model of their windows predicts,
# and their coherence fell short of one echo's in white noise (0.74-0.87 of it). Held to the
# coherence one echo has against the interference measured on the other tones of its windows
# (hil.estimation.reverb_band), the target is kept.
@pytest.mark.slow
@pytest.mark.parametrize(
    ("kind", "snr_db", "pd_min"),
    # Measured pd / false estimates per hop: still at 0 dB 0.967 / 0.040; slow (0.5 m/s)
    # 1.0 / 0; still at -10 dB 0.842 / 0.165. The false ones are a lone scatterer at
    # 1.0-1.07 m: a point echo at rest, which no test of one echo tells from a target; the
    # empty water does (gcas-bg: tests/evaluation/test_evaluation_scene_sweep.py).
    [
        ("still", 0.0, 0.9),
        ("slow", 0.0, 0.9),
        pytest.param(
            "still",
            -10.0,
            0.8,
            marks=pytest.mark.xfail(
                strict=True,
                reason="open (issue 26 item 3): at -10 dB the lone scatterer at 1.07 m is "
                "reported on 33 of 200 hops (0.165 per hop; 0.05 wanted)",
            ),
        ),
    ],
)
def test_a_slow_or_still_target_in_reverberation_is_kept_with_the_band_off(
    kind: str, snr_db: float, pd_min: float
) -> None:
    x, truth = _motion_input(kind, snr_db, 0.0, 4, min_range_m=1.0)
    rx = _receiver(reverb_speed_mps=0.0)
    false, pd = _false_and_moving_pd(run_blocks(rx, x), truth, faster_than_mps=-1.0)
    assert pd >= pd_min and false <= 0.05


@pytest.mark.slow
def test_diffuse_reverberation_is_counted_as_clutter_and_not_reported() -> None:
    # Thirty times the scatterers at the same scattering strength: the near water is a
    # diffuse patch, each tone answered with its own complex gain (coherence over all hops
    # about 0.53 of one echo's, within each tone 0.86).
    x, truth = _motion_input("still", 0.0, 0.0, 4, min_range_m=1.0, density_per_m3=0.3)
    rx = _receiver(reverb_speed_mps=0.0)
    est = run_blocks(rx, x)
    false, pd = _false_and_moving_pd(est, truth, faster_than_mps=-1.0)
    # Measured: 48 detections counted as clutter, none reported nearer than 5 m, no false
    # estimate; pd 0.918. Where the near water of a later hop arrives with the target's
    # boundary, the target is its window's second codeword
    # (hil.estimation.gcas.still_codewords: pd 0.625 without). Of the 15 boundaries missed,
    # 10 are one codeword in every code period, where stage 1 gives no still candidate at the
    # target's time.
    assert rx.clutter_count >= 30 and false == 0.0
    assert not [e for e in est if e.range_m < 5.0]
    # Said where it is (measured: 2.63 m at hop 10, 1.14 m at hop 23), each range once.
    ranges = [seen.range_m for seen in rx.clutter_seen]
    assert 1 <= len(ranges) <= 5 and all(1.0 <= r <= 5.0 for r in ranges)
    assert rx.notices() == rx.clutter_seen
    assert pd >= 0.9


# sim-03's band-off case (docs/results.md): a target at 10-25 m/s, -10 dB per-sample SNR,
# volume reverberation of 0.01 scatterers/m³ from 5 m. A few scatterers in one near range
# cell fit as one echo whose coherence passes the relative test (the neighbours load the
# other tones as much as it loads its own) but never the white-noise one, which a point echo
# passes on the hops its tones leave clear: reported only where a point echo was confirmed
# (hil.estimation.gcas.point_echoes).
@pytest.mark.slow
@pytest.mark.parametrize(
    ("point", "rep", "srr_db", "false_max"),
    # Measured false estimates in 46-47 hops: 25 -> 2 (0 dB SRR, 10.8 m/s), 9 -> 1 (+5 dB
    # SRR, 19.7 m/s); every boundary detected before and after.
    [(14, 0, 0.0, 2), (16, 0, 5.0, 1)],
)
def test_near_reverberation_is_not_reported_as_still_targets_with_the_band_off(
    point: int, rep: int, srr_db: float, false_max: int
) -> None:
    from hil.evaluation.trials_ch6 import ch6_receiver_trial

    params = {"receiver": "gcas", "m_hops": 10, "snr_db": -10.0, "speed_mps": [10.0, 25.0],
              "srr_db": srr_db, "reverb_speed_mps": 0.0}  # fmt: skip
    out = ch6_receiver_trial(params, np.random.SeedSequence(2067, spawn_key=(point, rep)))
    assert out["pd"] == 1.0 and out["n_false"] <= false_max


def test_two_peaks_of_one_echo_at_one_boundary_give_one_estimate() -> None:
    # The JIFS comparison's trial 343 (4.28 m/s at 69.6 m, -20 dB, ±25.72 m/s span): two
    # peaks of the target at hop 31, 0.9 µs apart, both refined onto it, were both reported
    # (68.0228 and 68.0235 m, 4.2805 and 4.2807 m/s): the second is the same echo.
    from hil.evaluation.trials_ch6 import ch6_receiver_trial

    params = {"m_hops": 10, "speed_mps": [2.0, 10.0], "receiver": "gcas",
              "max_speed_mps": 25.72, "snr_db": -20.0}  # fmt: skip
    out = ch6_receiver_trial(params, np.random.SeedSequence(2072, spawn_key=(11, 13)))
    assert (out["n_detected"], out["n_truth"], out["n_false"]) == (47, 47, 0)
    assert out["n_estimates"] == 47


@pytest.mark.slow
def test_an_echo_beyond_the_span_followed_beside_a_still_one_is_not_reported() -> None:
    # An echo opening at 55 m/s from 5 m beside a still echo at 40 m, -10 dB, a 30 m/s span:
    # its fits (sources of its ghosts, past the guard band) are followed to keep it taken out
    # of other detections, but an estimate beyond the span is refused, not reported.
    # Measured: 91 estimates at -55 m/s before following was held to the span, none after.
    schedule = att_schedule()
    x = echo_samples(schedule, 5.0, -55.0, 1.5, snr_db=-10.0, seed=4) + echo_samples(
        schedule, 40.0, 0.0, 1.5
    )
    rx = _receiver()
    est = run_blocks(rx, x)
    assert all(abs(e.speed_mps) <= 30.0 for e in est)
    assert [s.side for s in rx.beyond_span] == ["opening"]
