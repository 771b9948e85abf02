"""The streaming GCAS receiver: input checks, the front end, one search strategy and the
readout, in that order (the algorithm: :mod:`hil.estimation.gcas`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from hil.errors import ConfigError
from hil.estimation.base import Estimate
from hil.estimation.first_arrival import FirstArrivalReadout
from hil.estimation.gcas.beyond_span import BeyondSpan, BeyondSpanCheck
from hil.estimation.gcas.clutter_seen import ClutterSeen
from hil.estimation.gcas.front_end import FrontEnd
from hil.estimation.gcas.ghost_inside import evidence_history_s
from hil.estimation.gcas.options import (
    COARSE_STEP,
    OPTION_NAMES,
    check_geometry,
    check_modes,
    check_option_names,
    resolve_cfar_lambda,
)
from hil.estimation.gcas.readout import ECHO_TEST, DetectionInfo, Readout
from hil.estimation.gcas.residual import ResidualSearch
from hil.estimation.gcas.search import SearchStrategy
from hil.estimation.gcas.search_full import FullSearch
from hil.estimation.gcas.search_two_stage import TwoStageSearch
from hil.estimation.gcas.sums import CodewordSums
from hil.estimation.gcas.threshold import Cfar
from hil.estimation.option_types import OptionNames
from hil.estimation.refine import CoherentRefiner
from hil.estimation.reverb_band import AUTO
from hil.signals.schedule import HopSchedule

#: Half-width of the refinement's speed search around the detector's speed, m/s: ten times
#: the noncoherent readout's speed error at −10 dB per-sample SNR (0.05 m/s on att), and
#: more than its bias next to the reverberation band's masked cells (up to 0.48 m/s at
#: 25 m/s; the search re-centres where the peak is at its edge).
REFINE_SPEED_SPAN_MPS = 0.5

MapCallback = Callable[[NDArray[np.float64], NDArray[np.float32], NDArray[np.float64]], None]


class GcasReceiver:
    """Streaming GCAS receiver; the algorithm is described in :mod:`hil.estimation.gcas`.

    Parameters
    ----------
    schedule:
        The transmit schedule (``random-cyclic`` or ``three-state``); the first input sample
        is at the schedule's t = 0.
    fs_hz:
        Input sample rate, Hz.
    sound_speed_mps, max_speed_mps, max_range_m:
        c (m/s), the Doppler search span ± (m/s) and the largest range reported (m).
    m_hops:
        Correlator length M, from the code's minimum (all M-hop codewords distinct) to
        :data:`M_MAX`.
    n_doppler:
        Number of Doppler hypotheses D.
    coherent:
        Coherent accumulated sum (phases restored) instead of the noncoherent default [R].
    pfa:
        False-alarm probability per update used to set λ when ``cfar_lambda`` is None.
    cfar_lambda:
        λ of the threshold ``μ̂ + λσ̂`` (overrides ``pfa``).
    runner_up_ratio:
        ρ: best codeword over the runner-up, >= 1.
    cfar_window_hops:
        Length of the trailing CFAR window, hops.
    cfar_mode:
        ``"bank"`` or ``"statistic"`` (module docstring, step 6).
    reverb_speed_mps, reverb_weight:
        Reverberation band: Doppler cells that stationary clutter of speed ``|v| <``
        ``reverb_speed_mps`` (m/s) fills get ``reverb_weight`` in the Doppler decision (0
        excludes them). Default ``"auto"``: the waveform's clutter main lobe
        (:mod:`hil.estimation.reverb_band`: targets slower than the Doppler resolution
        ``c/(2 f T_h)`` are not reported); 0 turns the band off (a stationary or slow target).
        Detections on the band's edge are refused (:attr:`in_band_count`).
    decimation:
        Baseband decimation R; default the largest that keeps the Doppler-scaled band.
    attenuation_db:
        Stop-band attenuation of the baseband low-pass, dB.
    search:
        ``"two-stage"`` (default: coarse correlators every ``coarse_step`` samples choose the
        hypothesis and the candidate times; exact sums only around each candidate) or
        ``"full"`` (every unit correlator at every baseband sample; the reference).
    coarse_step:
        Coarse step B of the two-stage search, baseband samples.
    range_readout, max_spread_s:
        ``"peak"`` (default): the boundary time is the peak of the accumulated sums (in
        multipath, the centroid of the arrivals); ``"first-arrival"``: the onset of the next
        tone, the direct path in a tank (:mod:`hil.estimation.first_arrival`; arrivals up to
        ``max_spread_s`` s before the peak; default 0.3 hop).
    refine:
        Measure each detection by coherent local maximum likelihood of delay and Doppler at
        the input rate over its ``M`` hops (:mod:`hil.estimation.refine`: the Cramér–Rao
        bound above threshold; each estimate then carries its own bounds). Default True;
        False keeps the detector's own readout. The first-arrival readout times the direct
        path itself, so refinement applies to the peak readout only.
    cancel:
        With the refinement, search the input again with the echoes measured lately taken
        out (:mod:`hil.estimation.gcas.residual`: a weaker echo beside a stronger one's
        Doppler row or ghost is no maximum of its own in the input). Default True; False
        searches the input once.
    on_map:
        Called as ``on_map(t_s, P, speed_mps)`` with the time–codeword map of each new stretch
        of baseband samples: times (s, shape ``(n,)``), ``P`` (shape ``(n, J)``) and the chosen
        Doppler hypothesis as a speed (m/s, shape ``(n,)``).
    """

    name = "gcas"

    def __init__(
        self,
        schedule: HopSchedule,
        fs_hz: float,
        *,
        sound_speed_mps: float,
        max_speed_mps: float,
        max_range_m: float,
        m_hops: int,
        n_doppler: int = 64,
        coherent: bool = False,
        pfa: float = 1e-3,
        cfar_lambda: float | None = None,
        runner_up_ratio: float = 1.05,
        cfar_window_hops: float = 8.0,
        cfar_mode: str = "bank",
        reverb_speed_mps: float | str | None = AUTO,
        reverb_weight: float = 0.0,
        decimation: int | None = None,
        attenuation_db: float = 70.0,
        on_map: MapCallback | None = None,
        search: str = "two-stage",
        coarse_step: int = COARSE_STEP,
        range_readout: str = "peak",
        max_spread_s: float | None = None,
        refine: bool = True,
        cancel: bool = True,
    ) -> None:
        check_geometry(schedule, fs_hz, sound_speed_mps, max_speed_mps, max_range_m, m_hops)
        check_modes(cfar_mode, runner_up_ratio, cfar_window_hops, search, range_readout)
        self.search, self.range_readout, self.cfar_mode = search, range_readout, cfar_mode
        self._first_arrival = (
            FirstArrivalReadout(
                schedule, float(fs_hz), int(m_hops), float(sound_speed_mps), max_spread_s
            )
            if range_readout == "first-arrival"
            else None
        )
        if not isinstance(refine, bool):
            raise ConfigError("refine", refine, "true or false")
        if not isinstance(cancel, bool):
            raise ConfigError("cancel", cancel, "true or false")
        self.schedule, self.fs_hz, self.on_map = schedule, float(fs_hz), on_map
        self.sound_speed_mps, self.max_speed_mps = float(sound_speed_mps), float(max_speed_mps)
        self.max_range_m, self.m_hops = float(max_range_m), int(m_hops)
        self.coherent, self.runner_up_ratio = bool(coherent), float(runner_up_ratio)

        def front_end() -> FrontEnd:
            return FrontEnd(
                schedule, self.fs_hz, sound_speed_mps=self.sound_speed_mps,
                max_speed_mps=self.max_speed_mps, m_hops=self.m_hops, n_doppler=n_doppler,
                reverb_speed_mps=reverb_speed_mps, reverb_weight=reverb_weight,
                decimation=decimation, attenuation_db=attenuation_db,
                cfar_window_hops=cfar_window_hops,
            )  # fmt: skip

        fe = self.front_end = front_end()
        self.baseband, self.grid, self.fs_bb = fe.baseband, fe.grid, fe.fs_bb
        self.tones_hz, self.hop_s, self.n_codewords = fe.tones_hz, fe.hop_s, fe.n_codewords
        self.lags = fe.lags
        #: The band's clutter speed in use, m/s (0: no band).
        self.reverb_speed_mps = fe.reverb_speed_mps
        #: Hypotheses whose detections are refused (the band's edge), shape ``(D,)``.
        self.refused_hypotheses = fe.refused_hypotheses
        self.cfar_lambda = resolve_cfar_lambda(
            cfar_lambda, pfa, self.m_hops, fe.n_codewords, cfar_mode
        )
        cfar = Cfar(cfar_mode, self.cfar_lambda, self.m_hops)
        self._refiner = self._beyond = None
        if refine and range_readout == "peak":
            # The refinement measures up to the end of the beyond-span check's guard band, and
            # fits the sources of ghosts as far as they lie (tone spacings past the span).
            guard = BeyondSpanCheck.guard_width_mps(self.sound_speed_mps, fe.center_hz, self.hop_s)
            self._refiner = CoherentRefiner(
                schedule, self.fs_hz, self.m_hops, self.sound_speed_mps,
                REFINE_SPEED_SPAN_MPS, self.max_speed_mps + guard, ECHO_TEST,
                window_speed_mps=BeyondSpanCheck.source_reach_mps(
                    self.tones_hz, self.max_speed_mps, self.sound_speed_mps, fe.center_hz,
                    self.hop_s,
                ),
            )  # fmt: skip
            self._beyond = BeyondSpanCheck(
                self._refiner, self.max_speed_mps, ECHO_TEST, hop_s=self.hop_s,
                center_hz=fe.center_hz, f_max_hz=float(np.max(self.tones_hz)),
            )  # fmt: skip
        self.refine = self._refiner is not None
        self._sums = CodewordSums(fe)
        self.strategy = self._make_search(fe, self._sums, search, cfar, coarse_step)
        #: The second search of successive cancellation (with the refinement and ``cancel``).
        self._residual: ResidualSearch | None = None
        if self._refiner is not None and cancel:
            twin = front_end()
            twin_search = self._make_search(
                twin, CodewordSums(twin), search, cfar, coarse_step, every_echo=False
            )
            self._residual = ResidualSearch(
                twin.baseband, twin_search, self.m_hops, self.hop_s * self.fs_hz
            )
        self.cancel = self._residual is not None
        # The readouts re-read the input at a peak's boundary when the peak comes out, up to
        # the search's decision lag after its samples arrived: they keep that much more.
        for reader in (self._refiner, self._first_arrival):
            if reader is not None:
                reader.allow_lag(self.decision_lag_samples + self._evidence_samples(reader))
        self.readout = Readout(
            fe, max_range_m=self.max_range_m, coherent=self.coherent,
            first_arrival=self._first_arrival, unit_values=self.strategy.unit_values,
            refiner=self._refiner, receiver=self.name, beyond_span=self._beyond,
        )  # fmt: skip
        self.reset()
        self._warm_up()

    def _evidence_samples(self, reader: object) -> int:
        """The input (samples) the refinement keeps beyond its own history and the decision
        lag for the search for a ghost's source inside the span (with the beyond-span check,
        whose geometry it shares: :func:`~hil.estimation.gcas.ghost_inside.
        evidence_history_s`); none for another reader."""
        if reader is not self._refiner or self._beyond is None:
            return 0
        period = self.schedule.period_hops
        seconds = evidence_history_s(period, self.hop_s, self.max_speed_mps, self.sound_speed_mps)
        return math.ceil(seconds * self.fs_hz)

    def _make_search(
        self,
        fe: FrontEnd,
        sums: CodewordSums,
        search: str,
        cfar: Cfar,
        coarse_step: int,
        every_echo: bool = True,
    ) -> SearchStrategy:
        """The strategy object of the ``search`` option (the only place it is read) on the
        front end ``fe``."""
        if search == "full":
            return FullSearch(
                fe, sums, cfar, coherent=self.coherent, runner_up_ratio=self.runner_up_ratio,
                still_codewords=self._refiner is not None,
            )  # fmt: skip
        # Several echoes per hop where the refinement's likelihood tells an echo from the
        # ghosts and sidelobes of another; the strongest one per hop where it does not.
        return TwoStageSearch(
            fe, cfar, coherent=self.coherent, runner_up_ratio=self.runner_up_ratio,
            coarse_step=coarse_step, every_echo=every_echo and self._refiner is not None,
        )  # fmt: skip

    def _warm_up(self) -> None:
        """Run every compiled kernel once on a few zeros, then forget it: the first call in a
        process loads the machine code from numba's cache (or compiles it, seconds), which must
        not happen inside the first live block. The map callback is not called."""
        on_map, self.on_map = self.on_map, None
        try:
            self.process(np.zeros(self.baseband.decimation * 64))
            self.strategy.warm_up()
            if self._residual is not None:
                self._residual.strategy.warm_up()
            if self._refiner is not None:
                self._refiner.warm_up()
        finally:
            self.on_map = on_map
        self.reset()

    # ------------------------------------------------------------------ construction
    @classmethod
    def option_names(cls) -> OptionNames:
        """The keyword options of :meth:`from_options` (:data:`~.options.OPTION_NAMES`)."""
        return OptionNames(OPTION_NAMES)

    @classmethod
    def from_options(
        cls,
        schedule: HopSchedule,
        fs_hz: float,
        *,
        sound_speed_mps: float,
        max_speed_mps: float,
        max_range_m: float,
        m_hops: int,
        **extra: Any,
    ) -> GcasReceiver:
        """The registry's common constructor (:mod:`hil.estimation.registry`)."""
        check_option_names(extra)
        return cls(
            schedule,
            fs_hz,
            sound_speed_mps=sound_speed_mps,
            max_speed_mps=max_speed_mps,
            max_range_m=max_range_m,
            m_hops=m_hops,
            **extra,
        )

    # ------------------------------------------------------------------ counts
    @property
    def n_tones(self) -> int:
        """Number of tones K."""
        return self.front_end.n_tones

    @property
    def inconsistent_count(self) -> int:
        """Detections whose hop index did not advance as the elapsed time predicts."""
        return self.readout.inconsistent_count

    @property
    def refused_count(self) -> int:
        """Detections refused for a delay beyond ``max_range_m`` (or a negative one: an echo
        followed past the transducer)."""
        return self.readout.refused_count

    @property
    def in_band_count(self) -> int:
        """Detections refused as the edge leak of an echo inside the reverberation band."""
        return self.readout.in_band_count

    @property
    def incoherent_count(self) -> int:
        """Detections the refinement refused as no one echo of the schedule: a still echo
        read at the tone spacing's speed, an echo beyond the Doppler span, noise."""
        return self.readout.incoherent_count

    def refusals(self) -> dict[str, int]:
        """Detections refused since the last reset, by reason
        (:class:`~hil.estimation.base.CountsRefusals`): the counts below."""
        return {
            "not_one_echo": self.incoherent_count,
            "clutter": self.clutter_count,
            "in_band": self.in_band_count,
            "beyond_span": self.beyond_span_count,
            "beyond_max_range": self.refused_count,
            "unmeasured": self.unmeasured_count,
            "same_echo": self.readout.same_echo_count,
            "ended": self.readout.ended_count,
        }

    @property
    def followed_count(self) -> int:
        """Estimates of echoes measured lately at the next boundary their fits put, where no
        detection brought it (another echo's ghost or response held their row's maximum;
        :meth:`~hil.estimation.gcas.readout.Readout.decide_all`)."""
        return self.readout.followed_count

    @property
    def clutter_count(self) -> int:
        """Detections refused as clutter: diffuse reverberation in the echo's Doppler cells
        (the band off), not one point echo (:mod:`hil.estimation.reverb_band`)."""
        return self.readout.clutter_count

    @property
    def beyond_span_count(self) -> int:
        """Detections refused as an echo beyond the Doppler span: its edge leak, or a fit
        past the span (:mod:`hil.estimation.gcas.beyond_span`; with the refinement only)."""
        return 0 if self._beyond is None else self._beyond.count

    @property
    def beyond_span(self) -> list[BeyondSpan]:
        """Echoes seen beyond the Doppler span since the last reset: the first sighting on
        each side (closing, opening), in the order seen; empty without the refinement."""
        return [] if self._beyond is None else list(self._beyond.sightings)

    @property
    def clutter_seen(self) -> list[ClutterSeen]:
        """Where clutter was refused since the last reset: one notice per range more than
        :data:`~hil.estimation.gcas.clutter_seen.CLUTTER_NOTICE_M` from the others, in the
        order seen (:mod:`hil.estimation.gcas.clutter_seen`)."""
        return list(self.readout.clutter_seen.sightings)

    def notices(self) -> list[BeyondSpan | ClutterSeen]:
        """Everything the receiver says of what it refused since the last reset, in the
        order seen (:class:`~hil.estimation.base.SaysNotices`): :attr:`beyond_span` and
        :attr:`clutter_seen`."""
        return list(self.readout.notices)

    @property
    def unmeasured_count(self) -> int:
        """Detections refused because the refinement could not measure them: their hops
        reach back before the input's start or a gap."""
        return self.readout.unmeasured_count

    @property
    def last_detection(self) -> DetectionInfo | None:
        """Diagnostics of the latest accepted detection."""
        return self.readout.last_detection

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget all state; the next sample is sample 0 again."""
        self._samples_seen = 0
        self._restart(0)
        self.readout.reset()

    @property
    def decision_lag_samples(self) -> int:
        """Input samples an estimate's boundary can lie behind the newest input sample when
        it comes out: the search's decision lag (:attr:`SearchStrategy.decision_lag`,
        baseband samples of ``R`` input samples), the low-pass's group delay and two baseband
        samples (the newest baseband sample is up to one behind the input, one of margin)."""
        r = self.baseband.decimation
        return (self.strategy.decision_lag + 2) * r + math.ceil(self.baseband.group_delay)

    @property
    def samples_seen(self) -> int:
        """Input samples consumed so far (gaps included)."""
        return self._samples_seen

    def _restart(self, input_index: int) -> None:
        """Restart every accumulation at absolute input sample ``input_index``."""
        self.baseband.reset(input_index)
        if self._first_arrival is not None:
            self._first_arrival.reset(input_index)
        if self._refiner is not None:
            self._refiner.reset(input_index)
        self.strategy.reset(self.baseband.next_output_index)
        if self._residual is not None:
            self._residual.reset()
        #: The next input sample the second search takes (:meth:`_search_residual`).
        self._residual_from = int(input_index)
        self.readout.restart()

    # ------------------------------------------------------------------ streaming
    def process(self, block: ArrayLike, *, gap_before: int = 0) -> list[Estimate]:
        """Consume real samples (shape ``(n,)``); return the estimates completed by them.

        ``gap_before`` samples are missing before this block: estimates still pending are
        finalised, the time base advances and every accumulation restarts.
        """
        x = self._checked(block, gap_before)
        out: list[Estimate] = []
        if gap_before:
            out += self.flush()
            self._samples_seen += int(gap_before)
            self._restart(self._samples_seen)
        if self._residual is None:
            return out + self._search(x)
        # Stretches on a fixed grid of input samples, each searched again with the echoes
        # measured by then taken out (:mod:`hil.estimation.gcas.residual`).
        step, i = self._residual.step, 0
        while i < x.shape[0]:
            j = min(x.shape[0], i + step - (self._samples_seen % step))
            out += self._search(x[i:j])
            if self._samples_seen % step == 0:
                out += self._search_residual()
            i = j
        return out

    def _search(self, x: NDArray[np.float64]) -> list[Estimate]:
        """The first search on input samples ``x`` (shape ``(n,)``, the next of the stream):
        the estimates completed by them."""
        if self._first_arrival is not None:
            self._first_arrival.push(x, self._samples_seen)
        if self._refiner is not None:
            self._refiner.push(x, self._samples_seen)
        self._samples_seen += x.shape[0]
        y = self.baseband.process(x)
        if y.shape[0] == 0:
            return []
        peaks = self.strategy.process(y)
        if self.on_map is not None:
            self._emit_map(self.on_map, y.shape[0])
        return self.readout.decide_all(peaks)

    def _search_residual(self) -> list[Estimate]:
        """The second search on the input since it last ran (up to a stretch's end or the
        input's), with the echoes measured by now taken out."""
        residual, refiner = self._residual, self._refiner
        assert residual is not None and refiner is not None
        first, stop = self._residual_from, self._samples_seen
        if stop <= first:
            return []
        self._residual_from = stop
        known = refiner.known_input(first, stop - first)
        start = first
        if known is not None and not residual.running:
            # It starts on the input before, as far back as its M hops (the echoes' fits
            # hold there too): what they hid is found at once.
            start = first - residual.lead
        start, x = refiner.recent_input(start)
        if start != first:
            known = refiner.known_input(start, x.shape[0])
        peaks = residual.process(x, known, start)
        return self.readout.decide_all(peaks, residual=True) if peaks else []

    def _checked(self, block: ArrayLike, gap_before: int) -> NDArray[np.float64]:
        """``block`` as a 1-D float array of finite samples; ``gap_before`` a count."""
        x = np.asarray(block, dtype=np.float64)
        if x.ndim != 1:
            raise ConfigError("block", f"shape {x.shape}", "a 1-D array of real samples")
        if int(gap_before) != gap_before or gap_before < 0:
            raise ConfigError("gap_before", gap_before, "an integer >= 0 (samples)")
        bad = ~np.isfinite(x)
        if bad.any():
            i = int(np.argmax(bad))
            raise ConfigError(
                "block",
                f"{x[i]} at sample index {self._samples_seen + gap_before + i}",
                "finite samples (no NaN or inf)",
                "check the acquisition; mark missing samples with gap_before instead",
            )
        return x

    def flush(self) -> list[Estimate]:
        """End of input: decide the candidates still waiting for their look-ahead."""
        out = self.readout.decide_all(self.strategy.flush())
        if self._residual is not None:
            out += self._search_residual()
            out += self.readout.decide_all(self._residual.flush(), residual=True)
        return out

    @property
    def next_decision_index(self) -> int:
        """Input sample count (as :attr:`samples_seen`) the stream must reach before the next
        estimate can come out: :meth:`process` returns nothing while ``samples_seen`` stays
        below it (an unbroken stream; a gap flushes). A live loop may wait for that many
        samples instead of calling once per block: fewer, larger calls, the same estimates,
        emitted no later. The full search gives no such bound (``samples_seen``)."""
        first = self.strategy.next_decision_index(self._samples_seen)
        if self._residual is None:
            return first
        second = self._residual.next_decision_index(self._residual_from)
        if second is None:
            return first
        # The second search decides at the end of a stretch (:meth:`process`).
        step = self._residual.step
        return min(first, -(-max(second, self._residual_from + 1) // step) * step)

    # ------------------------------------------------------------------ diagnostics
    def _emit_map(self, on_map: MapCallback, count: int) -> None:
        """The time–codeword map of the last ``count`` baseband samples to ``on_map``. It
        costs ``J·M·K`` per sample, so it is computed only for a callback (detection
        evaluates the codeword sums only around candidate peaks)."""
        idx, d_map = self.strategy.map_hypotheses(count)
        on_map(
            self.baseband.time_of(idx),
            self._codeword_sums(idx, d_map, self.coherent),
            self.grid.speeds_mps[d_map].astype(np.float64),
        )

    def _codeword_sums(
        self, idx: NDArray[np.int64], dcol: NDArray[np.int64], coherent: bool
    ) -> NDArray[np.float32]:
        """``A[n, d_n, j]`` for samples ``idx`` (shape ``(n,)``) at hypotheses ``dcol``."""
        return self._sums.reduce(self.strategy.terms(idx, dcol), idx, dcol, coherent)

    def accumulated_sums(self, count: int) -> tuple[NDArray[np.float64], NDArray[np.float32]]:
        """The full ``A[n, d, j]`` for the last ``count`` baseband samples (diagnostics).

        Returns times (s, shape ``(count,)``) and ``A`` (shape ``(count, D, J)``), computed
        from the retained unit-correlator history; ``count`` is limited to the samples since
        the last restart.
        """
        idx = self.strategy.retained(count)
        full = np.stack(
            [
                self._codeword_sums(idx, np.full(idx.shape[0], d, dtype=np.int64), self.coherent)
                for d in range(self.grid.size)
            ],
            axis=1,
        )
        return self.baseband.time_of(idx), full
