"""Arithmetic cost per output sample of GCAS and of matched-filter banks (seed Fig 5.15) [D].

Counted in complex multiplications per input/output sample (one new lag of every correlator
per sample). Symbols: N_F tones, D Doppler hypotheses, J candidate codewords, M hops per
codeword, N_h samples per hop.

- **GCAS** (SPEC §3.8): the N_F·D unit correlators in the recursive form cost one complex
  multiply each per sample (the heterodyne; the moving sum is a running sum, i.e. additions),
  plus |u|² (counted as one complex multiply); the accumulated sums over M hops and J
  codewords are additions only. Multiplies: ``2·N_F·D`` (``N_F·D`` without the |u|²), which
  does not grow with M.
- **Direct matched-filter bank**: J·D correlators of length M·N_h, each a full dot product per
  output sample: ``J·D·M·N_h`` complex multiplies, linear in M.
- **FFT overlap-save bank** at the input rate (the seed's Fig 5.15 anchor): per block of
  ``S = N − L + 1`` outputs (``L = M·N_h``, ``N`` the power of two >= 2L): one N-point FFT of
  the input, then per correlator N spectral products and one N-point inverse FFT
  (``N/2·log2 N`` complex multiplies for a radix-2 FFT). Per output sample:
  ``[N/2·log2 N + J·D·(N + N/2·log2 N)] / S``, growing like log M. The ``mfbank`` receiver
  (:mod:`hil.estimation.mfbank`) mixes and decimates to baseband first, which divides this by
  about the decimation; its own count is
  :attr:`~hil.estimation.mfbank.MatchedFilterBank.mults_per_sample`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError


def _count(field: str, value: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ConfigError(field, value, "an integer >= 1")
    return int(value)


def fft_mults(n: int) -> float:
    """Complex multiplies of an n-point radix-2 FFT: ``n/2 · log2 n``.

    >>> fft_mults(1024)
    5120.0
    """
    return n / 2.0 * math.log2(n)


def gcas_mults_per_sample(n_tones: int, n_doppler: int, *, include_power: bool = True) -> float:
    """GCAS complex multiplies per sample: ``N_F·D`` heterodynes (+ ``N_F·D`` for |u|²).

    >>> gcas_mults_per_sample(4, 64)
    512.0
    """
    n = _count("n_tones", n_tones) * _count("n_doppler", n_doppler)
    return float(2 * n if include_power else n)


def gcas_adds_per_sample(n_tones: int, n_doppler: int, n_codewords: int, m_hops: int) -> float:
    """GCAS complex/real additions per sample: 2 per running sum, ``M − 1`` per accumulated sum.

    >>> gcas_adds_per_sample(4, 64, 17, 10)
    10304.0
    """
    nf, d = _count("n_tones", n_tones), _count("n_doppler", n_doppler)
    j, m = _count("n_codewords", n_codewords), _count("m_hops", m_hops)
    return float(2 * nf * d + j * d * (m - 1))


def direct_bank_mults_per_sample(
    n_codewords: int, n_doppler: int, m_hops: int, hop_samples: int
) -> float:
    """Direct matched-filter bank: ``J·D·M·N_h`` complex multiplies per sample.

    >>> direct_bank_mults_per_sample(17, 64, 10, 1000)
    10880000.0
    """
    return float(
        _count("n_codewords", n_codewords)
        * _count("n_doppler", n_doppler)
        * _count("m_hops", m_hops)
        * _count("hop_samples", hop_samples)
    )


def overlap_save_size(replica_samples: int) -> int:
    """FFT size used by the overlap-save bank: the power of two >= 2·L.

    >>> overlap_save_size(10_000)
    32768
    """
    length = _count("replica_samples", replica_samples)
    return 1 << int(math.ceil(math.log2(2 * length)))


def fft_bank_mults_per_sample(
    n_codewords: int, n_doppler: int, m_hops: int, hop_samples: int
) -> float:
    """FFT overlap-save bank complex multiplies per output sample (module docstring).

    >>> round(fft_bank_mults_per_sample(17, 64, 10, 1000))
    13320
    """
    jd = _count("n_codewords", n_codewords) * _count("n_doppler", n_doppler)
    length = _count("m_hops", m_hops) * _count("hop_samples", hop_samples)
    n = overlap_save_size(length)
    step = n - length + 1
    return (fft_mults(n) + jd * (n + fft_mults(n))) / step


def cost_table(
    m_values: ArrayLike, n_tones: int, n_doppler: int, n_codewords: int, hop_samples: int
) -> dict[str, NDArray[np.float64]]:
    """Multiplies per sample against M (shape ``(k,)``) for the three receivers (Fig 5.15).

    Keys: ``m_hops``, ``gcas``, ``direct_bank``, ``fft_bank`` (complex multiplies/sample) and
    ``gcas_adds`` (additions/sample).

    >>> t = cost_table([5, 10], 4, 64, 17, 1000)
    >>> t["gcas"].tolist(), t["direct_bank"].tolist()
    ([512.0, 512.0], [5440000.0, 10880000.0])
    """
    ms = np.asarray(m_values).reshape(-1)
    if ms.size == 0:
        raise ConfigError("m_values", [], "at least one M")
    rows = [int(m) for m in ms]
    return {
        "m_hops": np.array(rows, dtype=float),
        "gcas": np.array([gcas_mults_per_sample(n_tones, n_doppler) for _ in rows]),
        "gcas_adds": np.array(
            [gcas_adds_per_sample(n_tones, n_doppler, n_codewords, m) for m in rows]
        ),
        "direct_bank": np.array(
            [direct_bank_mults_per_sample(n_codewords, n_doppler, m, hop_samples) for m in rows]
        ),
        "fft_bank": np.array(
            [fft_bank_mults_per_sample(n_codewords, n_doppler, m, hop_samples) for m in rows]
        ),
    }
