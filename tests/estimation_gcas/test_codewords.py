"""The refinement's codewords, made once per schedule (hil.estimation.codewords): receivers
built from one schedule object share them, and a receiver reading shared codewords gives
the estimates, bit for bit, of one that made its own; each shared codeword equals a fresh
computation, before and after receivers have run on them."""

from __future__ import annotations

import numpy as np
import pytest

from hil.estimation.codewords import Codeword, CodewordBook
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule import HopSchedule

from .conftest import FS, echo_samples, make_gcas, run_blocks


def _new_schedule() -> HopSchedule:
    """A schedule object of its own (random-cyclic ``att``): nothing kept with it yet."""
    return check_design(get_preset("att").spec("random-cyclic"))


def _same(a: Codeword, b: Codeword) -> bool:
    """Every array and moment of ``a`` equal to ``b``'s, bit for bit."""
    return (
        all(
            np.array_equal(x, y) and x.dtype == y.dtype for x, y in zip(a.hops, b.hops, strict=True)
        )
        and np.array_equal(a.tones, b.tones)
        and (a.b_rms, a.t_rms, a.f0) == (b.b_rms, b.t_rms, b.f0)
    )


def _count_made(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Count the codewords made afresh (:meth:`Codeword.of`) for the rest of the test."""
    made, original = [0], Codeword.of

    def counted(schedule: HopSchedule, hop_index: int, m_hops: int, fs_hz: float) -> Codeword:
        made[0] += 1
        return original(schedule, hop_index, m_hops, fs_hz)

    monkeypatch.setattr(Codeword, "of", counted)
    return made


def test_a_second_receiver_of_one_schedule_makes_no_codeword(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The first receiver makes each of the code period's 17 codewords once (its warm-up
    makes them all); a second one built from the same schedule object makes none, and a
    receiver of another schedule object makes its own 17."""
    made = _count_made(monkeypatch)
    schedule = _new_schedule()
    make_gcas(schedule)
    assert made[0] == schedule.period_hops == 17
    make_gcas(schedule)
    assert made[0] == 17
    make_gcas(_new_schedule())
    assert made[0] == 34


def test_one_book_per_schedule_m_and_rate() -> None:
    """The book is kept per schedule object, M and input rate: asked again with the same
    three, the same book; another M, another rate or another schedule object, another."""
    schedule = _new_schedule()
    book = CodewordBook.of(schedule, 10, FS)
    assert CodewordBook.of(schedule, 10, FS) is book
    assert CodewordBook.of(schedule, 10.0, int(FS)) is book  # type: ignore[arg-type]
    others = (
        CodewordBook.of(schedule, 9, FS),
        CodewordBook.of(schedule, 10, 2 * FS),
        CodewordBook.of(_new_schedule(), 10, FS),
    )
    assert all(other is not book for other in others)
    assert [(b.m_hops, b.fs_hz) for b in others] == [(9, FS), (10, 2 * FS), (10, FS)]


def test_shared_codewords_give_the_estimates_of_own_ones() -> None:
    """Two receivers of one schedule (the second reads the codewords the first made) and one
    of an equal schedule object of its own give the same estimates, bit for bit (dataclass
    ==), on a lone target at 0 dB per-sample SNR (0.5 s: 39 estimates); and every
    codeword kept, after those runs, equals one made afresh."""
    schedule, own = _new_schedule(), _new_schedule()
    x = echo_samples(schedule, 60.0, 10.0, 0.5, snr_db=0.0, seed=3)
    first = run_blocks(make_gcas(schedule), x)
    second = run_blocks(make_gcas(schedule), x)
    alone = run_blocks(make_gcas(own), x)
    assert len(first) >= 35
    assert second == first
    assert alone == first
    book = CodewordBook.of(schedule, 10, FS)
    for key in range(schedule.period_hops):
        assert _same(book[key], Codeword.of(schedule, key, 10, FS)), key
        assert _same(book[key], CodewordBook.of(own, 10, FS)[key]), key


def test_a_codeword_of_a_later_period_is_the_first_periods() -> None:
    """``book[n]`` for hop n of any period is the codeword made from the first period (the
    same object): a codeword's figures never depend on the period it was first met in."""
    schedule = _new_schedule()
    book = CodewordBook.of(schedule, 10, FS)
    p = schedule.period_hops
    assert book[3 * p + 5] is book[5] is book[p + 5]
    assert _same(book[5], Codeword.of(schedule, 5, 10, FS))
