"""An echo that ends (a target that stops being seen) is reported up to the boundary whose
window's last hop still holds it, and no further; a continuous echo loses no estimate to that
rule (:data:`hil.estimation.refine.ENDED_CHANCE`)."""

from __future__ import annotations

import functools

import numpy as np
import pytest

from hil.estimation.base import Estimate

from .conftest import FS, att_schedule, echo_samples, make_gcas, run_blocks

R0, V0 = 70.0, 12.0  # 70 m, closing at 12 m/s
T_END = 0.8  # s of receive time: the echo's last sample
T_START = 0.5  # s of receive time: the echo's first sample


def _run(x: np.ndarray, m_hops: int) -> tuple[list[Estimate], int]:
    rx = make_gcas(att_schedule(), m_hops=m_hops)
    estimates = run_blocks(rx, x)
    return estimates, rx.refusals()["ended"]


@functools.cache
def _run_continuous(snr_db: float, seed: int, m_hops: int) -> tuple[tuple[Estimate, ...], int]:
    """The receiver's estimates and "ended" refusals over the continuous echo plus noise,
    computed once per process: the ended-echo test's reference run at M = 10, -10 dB is the
    continuous-echo test's run (the frozen estimates are read only)."""
    clean, noise = _echo_and_noise(snr_db, seed)
    estimates, ended = _run(clean + noise, m_hops)
    return tuple(estimates), ended


def _echo_and_noise(snr_db: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    clean = echo_samples(att_schedule(), R0, V0, 1.2)
    sigma = 1.0 / np.sqrt(2.0) / 10 ** (snr_db / 20.0)
    return clean, np.random.default_rng(seed).normal(0.0, sigma, clean.shape)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("m_hops", "snr_db", "ended"), [(10, -10.0, 5), (10, 0.0, 9), (29, 0.0, 24), (29, -10.0, 24)]
)
def test_an_echo_that_ends_is_not_reported_after_its_last_hop(
    m_hops: int, snr_db: float, ended: int
) -> None:
    # The detector's windows span M hops: for up to M - 1 boundaries after the echo's end a
    # window still holds it on its earlier hops. Only the boundary whose last hop straddles
    # the end (8.8 ms of its 10 ms hold the echo) is reported; before the end the estimates
    # are the continuous echo's, boundary for boundary. ``ended`` counts the refused
    # detections after the end: each is fitted from the fit before it (a warm start), so
    # the ended echo's windows are measured as its and refused as ended (while each was
    # searched afresh: 8 at M = 10, 0 dB, and 21 / 14 at M = 29, 0 / -10 dB, the rest then
    # refused as not one echo); at M = 10, 0 dB, 2 are the second search's (the input with
    # the measured echoes taken out, hil.estimation.gcas.residual).
    clean, noise = _echo_and_noise(snr_db, seed=3)
    cut = clean.copy()
    cut[int(T_END * FS) :] = 0.0
    whole, whole_ended = _run_continuous(snr_db, 3, m_hops)
    got, got_ended = _run(cut + noise, m_hops)
    hop_s = att_schedule().hop_s
    after = [e.t_s - T_END for e in got if e.t_s > T_END]
    assert len(after) == 1 and after[0] < 0.5 * hop_s
    assert [e.hop_index for e in got if e.t_s <= T_END] == [
        e.hop_index for e in whole if e.t_s <= T_END
    ]
    assert got_ended == ended
    assert whole_ended == 0


@pytest.mark.parametrize(
    ("m_hops", "snr_db", "count"),
    [(10, -10.0, 110), pytest.param(10, -20.0, 110, marks=pytest.mark.slow)],
)
def test_a_continuous_echo_loses_no_estimate_to_the_end_rule(
    m_hops: int, snr_db: float, count: int
) -> None:
    # At -20 dB a hop's share of the echo is noisy (about 0.3 of its amplitude, one sigma):
    # only a surely empty end is refused, and no estimate of an echo that is there is. There
    # 10 of the 110 boundaries are the echo followed where no detection brought them (one of
    # its fits collected 15 dB or more, FOLLOW_MARGIN_DB, and it is held on: 106 when the
    # latest fit alone was gated).
    estimates, ended = _run_continuous(snr_db, 3, m_hops)
    assert ended == 0
    assert len(estimates) == count


def test_an_echo_that_begins_is_reported_from_a_boundary_it_has_reached() -> None:
    # A window that holds the echo on its last hops only: the echo is there at its boundary,
    # and it is reported once the window holds enough of it to be detected and pass the echo
    # test (here 4 of its 10 hops, at -10 dB). No boundary before the echo's first sample.
    clean, noise = _echo_and_noise(-10.0, seed=4)
    late = clean.copy()
    late[: int(T_START * FS)] = 0.0
    estimates, _ = _run(late + noise, 10)
    first = min(e.t_s for e in estimates)
    hop_s = att_schedule().hop_s
    assert T_START + 4 * hop_s < first < T_START + 5 * hop_s
