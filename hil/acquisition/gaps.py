"""Gap detection on a stream of sample blocks: by sample index (and, with the protocol's
SequenceGap events, by frame sequence number)."""

from __future__ import annotations

from hil.acquisition.annotations import Annotation, AnnotationKind


class SampleGapDetector:
    """Checks that each block starts where the previous one ended.

    ``check(first, n)`` returns an annotation for a gap (samples never received) or an
    overlap (samples received again), else None, and advances the expected index.

    >>> det = SampleGapDetector()
    >>> det.check(0, 100), det.check(100, 100)
    (None, None)
    >>> det.check(250, 10)  # doctest: +ELLIPSIS
    Annotation(sample_index=200, kind=<AnnotationKind.GAP: 'gap'>, length=50, detail='...')
    >>> det.gap_samples, det.expected
    (50, 260)
    """

    def __init__(self) -> None:
        self.expected: int | None = None
        """Index the next block should start at (None before the first block)."""
        self.gap_samples = 0
        self.overlap_samples = 0

    def reset(self, expected: int | None = None) -> None:
        """Start over (a new stream) expecting ``expected`` next."""
        self.expected = expected

    def check(self, first: int, n: int) -> Annotation | None:
        """Annotation for the block at ``first`` of ``n`` samples, if it is out of line."""
        expected = self.expected
        note = None
        if expected is not None and first > expected:
            self.gap_samples += first - expected
            note = Annotation(
                expected,
                AnnotationKind.GAP,
                first - expected,
                f"samples {expected} .. {first - 1} missing (by sample index)",
            )
        elif expected is not None and first < expected:
            overlap = min(expected, first + n) - first
            self.overlap_samples += overlap
            note = Annotation(
                first, AnnotationKind.OVERLAP, overlap, f"block at {first} repeats samples"
            )
        if expected is None or first + n > expected:
            self.expected = first + n
        return note
