"""Binary sequences, three-state and random cyclic codes, Costas arrays."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.signals.binary_sequences import cyclic_words, de_bruijn, m_sequence
from hil.signals.costas import difference_triangle, is_costas, primitive_roots, welch_costas
from hil.signals.random_cyclic import (
    coincidence_matrix,
    cyclic_windows,
    distinct_window_count,
    has_no_repeat,
    has_unique_windows,
    is_orthogonal,
    minimum_distance,
    occupancy,
    random_cyclic_code,
)
from hil.signals.three_state import states_from_bits, three_state_code
from hil.signals.waveforms import (
    COMMON_FIELDS,
    FAMILIES,
    FAMILY_FIELDS,
    WaveformSpec,
    check_family_fields,
)


def test_issue_golden_three_state() -> None:
    # L_c = 3 with bits 00010111 gives states 0 1 2 0 2 0 2 1 (SPEC §2.1).
    bits = de_bruijn(3)
    assert "".join(map(str, bits)) == "00010111"
    assert states_from_bits(bits).tolist() == [0, 1, 2, 0, 2, 0, 2, 1]
    code = three_state_code(3)
    assert code.states.tolist() == [0, 1, 2, 0, 2, 0, 2, 1]


@pytest.mark.parametrize("order", range(1, 11))
def test_de_bruijn_three_state_closes_after_2_pow_lc(order: int) -> None:
    code = three_state_code(order)
    assert code.period_hops == 2**order
    # Closure: the transition out of the last hop returns to the first state.
    assert (code.states[-1] + 1 + code.bits[-1]) % 3 == code.states[0]
    assert has_no_repeat(code.states)
    words = cyclic_words(code.bits, order)
    assert sorted(words.tolist()) == list(range(2**order))


@pytest.mark.parametrize("order", range(2, 11))
def test_m_sequence_properties(order: int) -> None:
    m = m_sequence(order)
    assert m.shape[0] == 2**order - 1
    assert int(m.sum()) == 2 ** (order - 1)  # balance
    assert sorted(cyclic_words(m, order).tolist()) == list(range(1, 2**order))
    code = three_state_code(order, "mseq")
    assert code.period_hops == 3 * (2**order - 1)
    assert has_no_repeat(code.states)


def test_codeword_table() -> None:
    table = three_state_code(3).codeword_table()
    assert [row["name"] for row in table] == [f"cw{i}" for i in range(1, 9)]
    assert table[0] == {"name": "cw1", "bits": [0, 0, 0], "positions": [0], "tones": [0, 1, 2, 0]}
    assert table[5]["bits"] == [1, 0, 1] and table[5]["positions"] == [3]
    assert table[5]["tones"] == [0, 2, 0, 2]
    # Every codeword once per period for de Bruijn; the all-zero word never for an m-sequence.
    assert all(len(row["positions"]) == 1 for row in table)  # type: ignore[arg-type]
    mtable = three_state_code(3, "mseq").codeword_table()
    assert mtable[0]["positions"] == [] and mtable[0]["tones"] == []
    assert all(len(r["positions"]) == 3 for r in mtable[1:])  # type: ignore[arg-type]


def test_bad_orders_and_sources() -> None:
    with pytest.raises(
        ConfigError, match=r"order = 0 is not allowed: must be an integer in 1\.\.16"
    ):
        de_bruijn(0)
    with pytest.raises(ConfigError, match="order = 17"):
        m_sequence(17)
    with pytest.raises(ConfigError, match="source = 'gold'"):
        three_state_code(3, "gold")  # type: ignore[arg-type]


def test_coincidence_matrix_golden() -> None:
    code = [0, 1, 2, 1]
    w = coincidence_matrix(code, 2)
    # Windows ending at each hop: (0,1), (1,0), (2,1), (1,2) read newest first.
    assert w.tolist() == [[2, 0, 1, 0], [0, 2, 0, 1], [1, 0, 2, 0], [0, 1, 0, 2]]
    assert minimum_distance(code, 2) == 1
    assert is_orthogonal(code, 2, 1) and not is_orthogonal(code, 2, 2)
    assert cyclic_windows(code, 3).tolist() == [[2, 1, 0], [1, 0, 1], [0, 1, 2], [1, 2, 1]]


def test_coincidence_matrix_brute_force() -> None:
    code = random_cyclic_code(4, 17, 3, seed=5).code
    m = 7
    brute = np.array(
        [
            [sum(code[(i - k) % 17] == code[(j - k) % 17] for k in range(m)) for j in range(17)]
            for i in range(17)
        ]
    )
    np.testing.assert_array_equal(coincidence_matrix(code, m), brute)
    assert np.all(np.diag(brute) == m)


def test_occupancy_one_mark_per_column() -> None:
    rc = random_cyclic_code(4, 17, 3, seed=2)
    occ = rc.occupancy()
    assert occ.shape == (4, 17)
    assert occ.sum(axis=0).tolist() == [1] * 17
    assert np.argmax(occ, axis=0).tolist() == rc.code.tolist()
    assert occupancy([0, -1, 1], 2).tolist() == [[1, 0, 0], [0, 0, 1]]


def test_random_cyclic_seeded_and_best_of_candidates() -> None:
    a = random_cyclic_code(4, 17, 3, seed=11)
    b = random_cyclic_code(4, 17, 3, seed=11)
    c = random_cyclic_code(4, 17, 3, seed=12)
    assert a.code.tolist() == b.code.tolist()
    assert a.code.tolist() != c.code.tolist()
    best = random_cyclic_code(4, 17, 3, seed=11, candidates=10, m_hops=10)
    single = random_cyclic_code(4, 17, 3, seed=11, candidates=1, m_hops=10)
    assert best.d_min >= single.d_min
    assert best.d_min == minimum_distance(best.code, 10)


feasible = st.tuples(st.integers(3, 6), st.integers(2, 40), st.integers(2, 5)).filter(
    lambda t: distinct_window_count(t[0], t[2]) >= t[1] * 2 and t[2] <= t[1]
)


@settings(max_examples=40, deadline=None)
@given(feasible, st.integers(0, 2**31))
def test_random_cyclic_constraints_hold(args: tuple[int, int, int], seed: int) -> None:
    n_tones, length, window = args
    rc = random_cyclic_code(n_tones, length, window, seed=seed)
    assert rc.length == length
    assert rc.code.min() >= 0 and rc.code.max() < n_tones
    assert has_no_repeat(rc.code)  # wrap-around included
    assert has_unique_windows(rc.code, window)
    assert rc.d_min >= 1  # unique W-windows ⇒ codewords of M = W hops differ somewhere


@pytest.mark.parametrize(
    ("args", "field", "fragment"),
    [
        ((4, 17, 2), "window", "only 12 distinct windows exist"),
        ((1, 5, 1), "n_tones", "at least two tones"),
        ((3, 1, 1), "code_length", ">= 2"),
        ((2, 5, 2), "code_length", "even with 2 tones"),
        ((4, 17, 18), "code_length", ">= the window W = 18"),
    ],
)
def test_impossible_codes_are_refused(
    args: tuple[int, int, int], field: str, fragment: str
) -> None:
    with pytest.raises(ConfigError) as info:
        random_cyclic_code(*args)
    assert info.value.field == field
    assert fragment in str(info.value)


@pytest.mark.parametrize("p", [3, 5, 7, 11, 13, 17, 19, 23, 29, 31])
def test_welch_costas_difference_triangle(p: int) -> None:
    for root in primitive_roots(p):
        perm = welch_costas(p, root)
        assert sorted(perm.tolist()) == list(range(p - 1))
        for row in difference_triangle(perm):
            assert len(set(row.tolist())) == row.shape[0]
        assert is_costas(perm)


def test_costas_golden_and_negatives() -> None:
    assert welch_costas(5).tolist() == [1, 3, 2, 0]
    assert welch_costas(11, 2).tolist() == [1, 3, 7, 4, 9, 8, 6, 2, 5, 0]
    assert primitive_roots(11) == [2, 6, 7, 8]
    assert not is_costas([0, 1, 2, 3])  # a diagonal repeats every difference
    assert not is_costas([0, 2, 1, 1])  # not a permutation
    assert is_costas([1, 0, 2])
    with pytest.raises(ConfigError, match="prime = 12 is not allowed: must be a prime number"):
        welch_costas(12)
    with pytest.raises(ConfigError, match="primitive root of 11"):
        welch_costas(11, 3)


@pytest.mark.parametrize("candidates", [0, -3, 100_001, 10**8])
def test_random_cyclic_refuses_candidates_out_of_range(candidates: int) -> None:
    with pytest.raises(ConfigError) as err:
        random_cyclic_code(4, 17, 3, seed=1, candidates=candidates)
    message = str(err.value)
    assert "candidates" in message and str(candidates) in message
    assert "1 to 100000" in message and "draw fewer codes" in message


@pytest.mark.parametrize("family", FAMILIES)
def test_each_family_takes_the_settings_it_reads(family: str) -> None:
    reads = COMMON_FIELDS | FAMILY_FIELDS[family]
    check_family_fields(family, {field: 1 for field in reads} | {"order": None})
    others = sorted(set().union(*FAMILY_FIELDS.values()) - reads)
    for field in others:
        with pytest.raises(ConfigError) as err:
            check_family_fields(family, {field: 7})
        users = [f for f, fields in FAMILY_FIELDS.items() if field in fields]
        assert str(err.value) == (
            f"{field} = 7 is not allowed: must be a setting the {family} family reads; "
            f"only {', '.join(users)} read it: drop it, or choose that family"
        )


def test_the_family_fields_are_the_spec_s_and_an_unknown_family_is_named() -> None:
    spec_fields = set(WaveformSpec.__dataclass_fields__) - {"family"}
    assert COMMON_FIELDS | set().union(*FAMILY_FIELDS.values()) == spec_fields
    assert set(FAMILY_FIELDS) == set(FAMILIES)
    with pytest.raises(ConfigError, match=r"^family = 'nope' is not allowed: must be one of "):
        check_family_fields("nope", {"order": 3})
