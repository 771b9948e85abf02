"""Beside rest, a fit no stronger than half the still water at its own delay is that water's
leak through the hops' Doppler response, not a target
(:data:`hil.estimation.refine.STILL_SIDELOBE_FRACTION`): sim-03's trials at -10 dB SRR with
the default band."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from hil.evaluation.trials_ch6 import ch6_receiver_trial

#: sim-03's sweep seed and its grid points (hil/data/sweeps/sim03_reverberation.toml):
#: point 11 is 10-25 m/s targets, point 1 is 2-5 m/s targets, both at -10 dB SRR, default band.
SWEEP_SEED = 2067
POINTS = {1: [2.0, 5.0], 11: [10.0, 25.0]}


@functools.cache
def _trial(point: int, rep: int) -> dict[str, float]:
    """sim-03's trial ``rep`` at grid ``point``, run once per process: the parametrised cases
    at point 11 are three of the 30 trials the slow test sums (read only, never changed)."""
    params = {
        "receiver": "gcas", "m_hops": 10, "snr_db": -10.0, "speed_mps": POINTS[point],
        "srr_db": -10.0, "reverb_speed_mps": "auto",
    }  # fmt: skip
    out: dict[str, float] = ch6_receiver_trial(
        params, np.random.SeedSequence(SWEEP_SEED, spawn_key=(point, rep))
    )
    return out


@pytest.mark.slow
@pytest.mark.parametrize(
    ("point", "rep", "detected", "false"),
    [
        # A fast target in strong near reverberation: the still water at 6-22 m read at
        # 2.5-4.1 m/s, just outside the band, gave 2, 2 and 4 false estimates (0.24-0.44 of
        # the still echo at their delay); the target's boundaries are kept (47, 48 and 45
        # of 47, 48 and 47; 45 and 43 before a boundary missed just before the echo's next
        # detection was followed).
        (11, 0, 47, 0),
        (11, 1, 48, 0),
        (11, 9, 45, 0),
        # A 2-5 m/s target: its estimates stand above the still water at their delay (46
        # and 43 of 46 boundaries; 44 and 41 before those gaps were followed).
        (1, 0, 46, 0),
        (1, 21, 43, 0),
    ],
)
def test_the_still_waters_doppler_leak_is_not_reported(
    point: int, rep: int, detected: int, false: int
) -> None:
    out = _trial(point, rep)
    assert (out["n_detected"], out["n_false"]) == (detected, false)


@pytest.mark.slow
def test_beside_fast_targets_at_minus_10_db_srr_false_alarms_stay_below_0_8_per_second() -> None:
    # The 30 trials of sim-03's 10-25 m/s targets at -10 dB SRR with the default band: 1
    # false estimate in 13.8 s of scored time (4 with the grating lobe decided on the input
    # alone, 16 before the still-leak rule, the boundaries detected the same, 1106); 1105
    # with the second search on the input with the measured echoes taken out
    # (hil.estimation.gcas.residual) and a still target's cheaper hidden-echo measurements:
    # one boundary fewer, as in sim-03's run on 57daa53; 1142 with a boundary missed just
    # before the echo's next detection followed (CoherentRefiner.due); 1143 with a ghost
    # judged against the noise's reading at its echo's E/N0 (refine.GHOST_NOISE_Z); 1151
    # with the grating lobe judged on the input without its still water
    # (hil.estimation.still_lobe); the same with an echo held on while its fits pass the echo
    # test (refine.EchoFit.held), with one false estimate more, a cost of holding echoes
    # that this count tracks: the still water's leak at 6.2 m read at 4.1 m/s, followed one
    # boundary (rep 20).
    outs = [_trial(11, rep) for rep in range(30)]
    n_false = sum(int(o["n_false"]) for o in outs)
    window = sum(float(o["window_s"]) for o in outs)
    assert n_false == 2
    assert n_false / window < 0.8
    assert sum(int(o["n_detected"]) for o in outs) == 1151
