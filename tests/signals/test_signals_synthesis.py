"""Sampled synthesis: equals the analytic evaluation; any chunking gives identical output."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hil.errors import ConfigError
from hil.signals.presets import get_preset
from hil.signals.schedule import HopSchedule
from hil.signals.synthesis import BlockSynthesizer, synthesize
from hil.signals.waveforms import FAMILIES, build_schedule


@pytest.mark.parametrize("family", FAMILIES)
def test_synthesis_equals_analytic_evaluation(family: str) -> None:
    sch = build_schedule(get_preset("att").spec(family))
    fs = 100_000.0
    x = synthesize(sch, fs, 0.6)
    ref = sch.evaluate(np.arange(x.shape[0]) / fs)
    # Tones are exact to rounding; chirps carry the documented δ-quantisation error.
    tol = 1e-9 if np.all(sch.chirp_hz_per_s == 0) else 1e-7
    np.testing.assert_allclose(x, ref, rtol=0, atol=tol)


def test_fractional_hop_boundaries_follow_locate() -> None:
    # 1.37 ms hops at 10 kHz: boundaries fall between samples; a sample belongs to the hop
    # that sounds at its time, exactly as HopSchedule.locate says.
    sch = HopSchedule.from_segments(
        "f", [1000.0, 1700.0, 2900.0], [0, 2, 1], 0.00137, continuous_phase=False
    )
    fs = 10_000.0
    x = synthesize(sch, fs, 0.05)
    t = np.arange(x.shape[0]) / fs
    np.testing.assert_allclose(x, sch.evaluate(t), atol=1e-9)


def test_time_offset_and_amplitude() -> None:
    sch = build_schedule(get_preset("att").spec("random-cyclic")).shifted(0.00123)
    syn = BlockSynthesizer(sch, 100_000.0, amplitude=0.5, first_sample=12_345)
    x = syn.read(5000)
    ref = 0.5 * sch.evaluate((12_345 + np.arange(5000)) / 100_000.0)
    np.testing.assert_allclose(x, ref, atol=1e-9)
    assert syn.position == 17_345


def test_float32_output() -> None:
    sch = build_schedule(get_preset("att").spec("three-state"))
    x = synthesize(sch, 100_000.0, 0.1, dtype=np.float32)
    assert x.dtype == np.float32
    np.testing.assert_allclose(x, synthesize(sch, 100_000.0, 0.1), atol=1e-7)


@settings(max_examples=40, deadline=None)
@given(
    st.sampled_from(FAMILIES),
    st.lists(st.integers(0, 9000), min_size=1, max_size=8),
    st.integers(-5000, 5000),
)
def test_chunks_equal_whole(family: str, cuts: list[int], start: int) -> None:
    sch = build_schedule(get_preset("att").spec(family))
    fs = 100_000.0
    total = sum(cuts)
    whole = BlockSynthesizer(sch, fs, first_sample=start).read(total)
    syn = BlockSynthesizer(sch, fs, first_sample=start)
    parts = [syn.read(c) for c in cuts]
    np.testing.assert_array_equal(np.concatenate(parts), whole)


@pytest.mark.parametrize("family", FAMILIES)
def test_spans_read_in_any_order_equal_a_fresh_synthesizers(
    family: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    """One synthesizer keeps the hops it found for the next spans: spans read forward, back
    and far ahead are those of a synthesizer that reads only that span, and a stream of short
    consecutive reads finds its hops once per window, not once per read."""
    sch = build_schedule(get_preset("att").spec(family))
    fs = 100_000.0
    rng = np.random.default_rng(7)
    syn = BlockSynthesizer(sch, fs, amplitude=0.7)
    spans = [(-3000, 2500), (-500, 4000), (60_000, 1), (2_000_000, 9000), (100, 30_000)]
    starts, counts = rng.integers(-(10**5), 10**6, 20), rng.integers(1, 20_000, 20)
    spans += [(int(a), int(n)) for a, n in zip(starts, counts, strict=True)]
    for first, n in spans:
        fresh = BlockSynthesizer(sch, fs, amplitude=0.7).render(first, n)
        assert syn.render(first, n).tobytes() == fresh.tobytes()
    found = {"n": 0}
    real = BlockSynthesizer._first_samples

    def counted(self: BlockSynthesizer, *args: np.ndarray) -> np.ndarray:
        found["n"] += 1
        return real(self, *args)

    monkeypatch.setattr(BlockSynthesizer, "_first_samples", counted)
    stream = BlockSynthesizer(sch, fs)
    for _ in range(200):
        stream.read(500)  # 1 s: 100 hops of 10 ms at most
    assert 1 <= found["n"] <= 3


def test_blocks_iterator() -> None:
    sch = build_schedule(get_preset("att").spec("random-cyclic"))
    blocks = list(BlockSynthesizer(sch, 100_000.0).blocks(1000, 7))
    np.testing.assert_array_equal(np.concatenate(blocks), synthesize(sch, 100_000.0, 0.07))


def test_bad_synthesis_arguments() -> None:
    sch = build_schedule(get_preset("att").spec("random-cyclic"))
    with pytest.raises(ConfigError, match=r"fs_hz = 0\.0 is not allowed: must be > 0 Hz"):
        BlockSynthesizer(sch, 0.0)
    with pytest.raises(ConfigError, match=r"duration_s = -1\.0"):
        synthesize(sch, 1000.0, -1.0)
    with pytest.raises(ConfigError, match="n_samples = -3"):
        BlockSynthesizer(sch, 1000.0).render(0, -3)
    with pytest.raises(ConfigError, match="block_size = 0"):
        next(BlockSynthesizer(sch, 1000.0).blocks(0))
