"""GCAS front end: the complex baseband, the Doppler hypotheses and their reverberation band,
and the sample counts every search derives from them (SPEC §3 steps 1–2)."""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from hil.estimation.baseband import ComplexBaseband
from hil.estimation.doppler_grid import DopplerGrid, doppler_grid, speed_to_alpha
from hil.estimation.gcas.options import TRANSITION_FACTOR
from hil.estimation.reverb_band import clutter_cells, edge_hypotheses, resolve_reverb_speed
from hil.signals.schedule import HopSchedule

#: Guard around every tone's reverberation band, in unit-correlator main lobes (1/T_h).
#: 0.5 is the narrowest guard that leaves no ghost beside clutter plus a target; a wider one
#: does not remove the ghost but moves it to the first unmasked hypothesis past the guard.
REVERB_GUARD_LOBES = 0.5


class FrontEnd:
    """What every search of one receiver shares, fixed at construction.

    Attributes (units): ``baseband`` (:class:`~hil.estimation.baseband.ComplexBaseband`
    centred on ``center_hz``, rate ``fs_bb`` Hz); ``grid`` (the ``D`` Doppler hypotheses);
    ``nu`` (``ν[d, k] = α_d f_k − f_c``, Hz, shape ``(D, K)``); ``tone_w`` (reverberation
    weights per unit-correlator cell, shape ``(D, K)``, None without a band);
    ``refused_hypotheses`` (shape ``(D,)``); ``lags`` (``ℓ_{d,m} = round(m L_d)``, baseband
    samples, shape ``(D, M)``); ``n_min``/``n_max`` (shortest/longest window ``N_d``);
    ``half_width`` (``N_min/2``: the candidate look-ahead); ``search_half`` (``W``);
    ``cfar_window`` (trailing CFAR window) and ``settle`` (samples before the sums are full),
    all baseband samples.
    """

    def __init__(
        self,
        schedule: HopSchedule,
        fs_hz: float,
        *,
        sound_speed_mps: float,
        max_speed_mps: float,
        m_hops: int,
        n_doppler: int,
        reverb_speed_mps: float | str | None,
        reverb_weight: float,
        decimation: int | None,
        attenuation_db: float,
        cfar_window_hops: float,
    ) -> None:
        self.schedule = schedule
        self.fs_hz = float(fs_hz)
        self.sound_speed_mps = c = float(sound_speed_mps)
        self.max_speed_mps = float(max_speed_mps)
        self.m_hops = m = int(m_hops)
        self.code = schedule.code.astype(np.int64)
        self.n_codewords = int(self.code.shape[0])
        self.hop_s = schedule.hop_s
        self.tones_hz = tones = schedule.tones_hz
        self.center_hz = center = 0.5 * (float(tones.min()) + float(tones.max()))
        self.baseband = self._baseband(decimation, attenuation_db)
        self.fs_bb = self.baseband.fs_out_hz
        #: The band's clutter speed in use, m/s (0: no band).
        self.reverb_speed_mps = resolve_reverb_speed(
            reverb_speed_mps, tones, self.hop_s, c, self.max_speed_mps
        )
        self.reverb_weight = float(reverb_weight)
        self.grid: DopplerGrid = doppler_grid(
            self.max_speed_mps, int(n_doppler), c, self.hop_s, self.fs_bb,
            reverb_speed_mps=self.reverb_speed_mps, reverb_weight=reverb_weight,
        )  # fmt: skip
        self.nu = self.grid.frequencies(tones, center)
        self.tone_w = self._reverb_tone_mask()
        #: Hypotheses whose detections are refused (the band's edge; see reverb_band).
        self.refused_hypotheses = self._refused_hypotheses()
        self.lags = np.round(np.arange(m)[None, :] * self.grid.exact_lengths[:, None]).astype(
            np.int64
        )
        self.n_min = int(self.grid.lengths.min())
        self.n_max = int(self.grid.lengths.max())
        self.half_width = max(1, self.n_min // 2)
        self.cfar_window = max(2, int(round(cfar_window_hops * self.hop_s * self.fs_bb)))
        self.settle = (
            int(self.lags.max()) + self.n_max + self.baseband.n_taps // self.baseband.decimation + 2
        )
        # Candidate search window (baseband samples) around a peak of the group statistic:
        # the comb uses the integer lag N_d, so its peak may sit up to (M − 1)|N_d − L_d|/2
        # <= (M − 1)/4 samples from the peak of the exactly lagged codeword sums.
        self.search_half = min(int(math.ceil((m - 1) / 4.0)) + 2, max(1, self.half_width - 1))
        # One Doppler resolution cell of a hop, c/(2 f_c T_h) (m/s), in hypotheses: the main
        # lobe's half-width of one echo across the grid.
        cell_mps = c / (2.0 * center * self.hop_s)
        step = self.grid.speed_step_mps
        self.lobe_hypotheses = max(1, int(math.ceil(cell_mps / step))) if step > 0 else 1

    @property
    def n_tones(self) -> int:
        """Number of tones K."""
        return int(self.tones_hz.shape[0])

    def _baseband(self, decimation: int | None, attenuation_db: float) -> ComplexBaseband:
        """The baseband whose band holds every Doppler-scaled tone plus a sinc main lobe;
        ``decimation`` defaults to the largest that keeps that band."""
        c, v, tones, center = (
            self.sound_speed_mps,
            self.max_speed_mps,
            self.tones_hz,
            self.center_hz,
        )
        a_lo, a_hi = speed_to_alpha(-v, c), speed_to_alpha(v, c)
        band = max(abs(a_hi * tones.max() - center), abs(a_lo * tones.min() - center))
        passband = float(band) + 2.0 / self.hop_s
        if decimation is None:
            decimation = max(1, int(self.fs_hz / (2.0 * TRANSITION_FACTOR * passband)))
        return ComplexBaseband(
            self.fs_hz,
            center,
            decimation=int(decimation),
            passband_hz=passband,
            attenuation_db=attenuation_db,
        )

    def _reverb_tone_mask(self) -> NDArray[np.float32] | None:
        """Per-(d, k) weights of the reverberation band, shape ``(D, K)``; None without one.

        The unit correlator ``(d, k)`` listens at ``α_d f_k``; it sees stationary clutter
        whenever that frequency lies within half a main lobe of the clutter band of ANY tone
        ``k'`` (:func:`~hil.estimation.reverb_band.clutter_cells`), not only ``k' = k``: a
        stationary echo of tone ``k'`` looks like tone ``k`` moving at the speed where
        ``α_d f_k = f_k'`` (a ghost speed). Such cells get ``reverb_weight`` in the group
        statistic and in the codeword sums [R]: the band is handled per tone in frequency.
        """
        if self.reverb_speed_mps <= 0.0:
            return None
        hit = clutter_cells(
            self.grid.alphas, self.tones_hz, self.reverb_speed_mps, self.sound_speed_mps,
            REVERB_GUARD_LOBES / self.hop_s, any_tone=True,
        )  # fmt: skip
        return np.where(hit, self.reverb_weight, 1.0).astype(np.float32)

    def _refused_hypotheses(self) -> NDArray[np.bool_]:
        """Hypotheses whose detections are refused, shape ``(D,)``: the edge of the band
        around zero Doppler (:func:`~hil.estimation.reverb_band.edge_hypotheses`). Cells
        masked as another tone's clutter (the ghost speeds) are not an edge: a target there
        keeps its other tones, and the codeword sums tell it from the clutter."""
        if self.reverb_speed_mps <= 0.0:
            return np.zeros(self.grid.size, dtype=bool)
        own = clutter_cells(
            self.grid.alphas, self.tones_hz, self.reverb_speed_mps, self.sound_speed_mps,
            REVERB_GUARD_LOBES / self.hop_s, any_tone=False,
        ).any(axis=1)  # fmt: skip
        in_band = own | (self.grid.weights < 1.0)
        return edge_hypotheses(np.where(in_band, 0.0, 1.0), self.reverb_weight > 0)
