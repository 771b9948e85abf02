"""The CFAR threshold's Erlang inverse survival function against scipy.special and against
the closed form summed in 50-digit decimals."""

from __future__ import annotations

import math
from decimal import Decimal, localcontext

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.estimation.erlang_tail import erlang_isf

#: (m, p, scipy.special.gammainccinv(m, p)) from scipy 1.17.1; the middle row is the default
#: receiver's per-test share at M = 5 (pfa 1e-3 over 17 codewords x 256 cells).
GOLDEN = [
    (1, 0.5, math.log(2.0)),
    (2, 0.5, 1.6783469900166612),
    (5, 1e-3 / (17 * 256), 25.176759302226806),
    (10, 1e-6, 32.71034051752392),
    (29, 1e-9, 73.69843484081191),
    (64, 1e-300, 919.7559049401982),
    (64, 0.5, 63.66697707166383),
]


def _erlang_survival(m: int, x: float) -> Decimal:
    """Q(m, x) = exp(-x) Σ_{k<m} x^k / k!, in 50-digit decimals (exact enough to judge x)."""
    with localcontext() as ctx:
        ctx.prec = 50
        xd, term, total = Decimal(x), Decimal(1), Decimal(1)
        for k in range(1, m):
            term = term * xd / k
            total += term
        return (-xd).exp() * total


@pytest.mark.parametrize(("m", "p", "expected"), GOLDEN)
def test_golden_values(m: int, p: float, expected: float) -> None:
    assert erlang_isf(m, p) == pytest.approx(expected, rel=1e-12, abs=0.0)


@settings(max_examples=300, deadline=None, derandomize=True)
@given(m=st.integers(1, 64), log10_p=st.floats(-300.0, math.log10(0.5)))
def test_equals_scipy_gammainccinv(m: int, log10_p: float) -> None:
    from scipy.special import gammainccinv

    p = 10.0**log10_p
    assert erlang_isf(m, p) == pytest.approx(float(gammainccinv(m, p)), rel=1e-12, abs=0.0)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(m=st.integers(1, 64), log10_p=st.floats(-300.0, math.log10(0.5)))
def test_the_closed_form_returns_p(m: int, log10_p: float) -> None:
    # d ln Q / dx = -1/S with S >= 1, so a relative error e of x moves Q by at most x e
    # (relative): this holds x to 1e-14.
    p = 10.0**log10_p
    x = erlang_isf(m, p)
    rel = abs(float(_erlang_survival(m, x) / Decimal(p)) - 1.0)
    assert rel <= 1e-14 * x


@pytest.mark.parametrize(("m", "p"), [(0, 0.1), (2.5, 0.1), (3, 0.0), (3, 0.6), (3, -1.0)])
def test_refuses_what_it_does_not_invert(m: float, p: float) -> None:
    with pytest.raises(ValueError, match=r"(m|p) = .*: the "):
        erlang_isf(m, p)  # type: ignore[arg-type]
