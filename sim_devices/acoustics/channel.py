"""The block-wise acoustic channel: transmit schedule in, calibrated receive blocks out.

Everything is in calibrated units. The transmit ``s(t)`` is the unit-amplitude schedule;
the source level ``SL`` (dB re 1 µPa @ 1 m, RMS) sets its pressure amplitude at 1 m,
``A = √2 · 10^(SL/20)`` µPa·m. Received pressures are in µPa. The receiver turns pressure into
volts with its sensitivity (dB re 1 V/µPa) and gain (dB) and into ADC counts, float samples in
``[-1, 1)`` with ``full_scale_v`` volts at 1. Beyond that the ADC clips, as a converter does,
and the clipped samples are counted (:attr:`Channel.clipped_samples`): a simulation never
clips silently. ``input_fs`` is the converter's input before clipping, for a simulated ADC
(board, audio interface) that clips and counts itself.

Components, each a pressure stream (µPa), summed per sample:

- target echoes: every target over every :func:`~sim_devices.acoustics.tank.echo_paths` path
  (:class:`~sim_devices.acoustics.grid_echo.GridEcho`: the path solved exactly on a 4 ms grid
  and interpolated, delay error below 1e-11 s, transmit to float32 precision), with gain
  ``A · 10^(TS/20) · R · D_tx(u_out) D_rx(u_back) / (r1 r2) · 10^(−α_abs (r1 + r2)/20000)``:
  target strength TS (dB re 1 m²), reflection ``R`` of the image pair (to
  ``image_order`` reflections per round trip), the projector's pressure response ``D_tx`` in the
  direction the path leaves it and the hydrophone's ``D_rx`` in the direction it arrives from
  (:mod:`~sim_devices.acoustics.directivity`), spherical spreading and absorption (dB/km) on
  each leg;
- the direct blast (:class:`DirectBlast`);
- the tank's own echoes, transmitter → boundaries → hydrophone, and its diffuse late tail
  (:class:`~sim_devices.acoustics.tank_response.TankEchoes`, ``tank``);
- volume reverberation (:class:`~sim_devices.acoustics.reverberation.VolumeReverberation`);
- noise (:class:`~sim_devices.acoustics.noise_generator.ShapedNoiseGenerator`).

Echoes and the direct blast are computed per sample from grid data fixed by absolute sample
index (served from fixed frames of :data:`ECHO_FRAME` samples); reverberation and noise are
fixed-frame streams: so :meth:`Channel.read` returns the same samples for any chunking. The
sonar equation terms match these components: see :func:`echo_level_db`.

Look-ahead: echoes are rendered in frames of :data:`ECHO_FRAME` samples and their paths
solved in batches of about 66 ms (:class:`~sim_devices.acoustics.grid_echo.GridEcho`), so the
trajectories (a ``Live`` stage too) are queried up to about 80 ms (at 1 MHz) past the last
sample read.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from hil.errors import ConfigError
from hil.signals.schedule import HopSchedule
from sim_devices.acoustics.delay import OneWayPath, PathSolution, TwoWayPath
from sim_devices.acoustics.directivity import Transducer
from sim_devices.acoustics.echo import TransmitWaveform
from sim_devices.acoustics.grid_echo import EchoBank, GridEcho
from sim_devices.acoustics.hop_phase import sample_phases
from sim_devices.acoustics.noise_generator import ShapedNoiseGenerator
from sim_devices.acoustics.reverberation import VolumeReverberation
from sim_devices.acoustics.tank import EchoPath, Offset, Tank, echo_paths
from sim_devices.acoustics.tank_response import TankEchoes, TankEchoSettings, tank_impulse_response
from sim_devices.acoustics.trajectory import FloatArray, Trajectory

#: Echo samples rendered at a time (the stream is cut into frames of this many samples).
ECHO_FRAME = 16384


def source_amplitude(source_level_db: float) -> float:
    """Pressure amplitude at 1 m (µPa·m) of a unit cosine radiated at ``SL`` dB re 1 µPa @ 1 m.

    >>> round(source_amplitude(0.0), 6)
    1.414214
    """
    return math.sqrt(2.0) * 10.0 ** (source_level_db / 20.0)


@dataclass(frozen=True)
class Receiver:
    """Hydrophone and ADC: ``counts = p · 10^((sensitivity + gain)/20) / full_scale_v``.

    >>> Receiver(-180.0, 40.0, 1.0).to_counts(np.array([1e4]))
    array([0.001])
    """

    sensitivity_db: float = -180.0
    gain_db: float = 0.0
    full_scale_v: float = 1.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.full_scale_v) and self.full_scale_v > 0):
            raise ConfigError("sonar.full_scale_v", self.full_scale_v, "> 0 V")

    @property
    def volts_per_upa(self) -> float:
        """V per µPa of the hydrophone and amplifier."""
        return 10.0 ** ((self.sensitivity_db + self.gain_db) / 20.0)

    def to_full_scale(self, pressure_upa: FloatArray) -> FloatArray:
        """The ADC input in full-scale units (1 = ``full_scale_v``), not clipped."""
        return pressure_upa * (self.volts_per_upa / self.full_scale_v)

    def to_counts(self, pressure_upa: FloatArray) -> FloatArray:
        """Float ADC samples in ``[-1, 1)`` (clipped) for pressures in µPa."""
        return clip_full_scale(self.to_full_scale(pressure_upa))[0]


#: Largest float ADC sample (a 24-bit converter's top code).
TOP_CODE = 1.0 - 2.0**-23


def clip_full_scale(x: FloatArray) -> tuple[FloatArray, int]:
    """``x`` (full-scale units) clipped to ``[-1, TOP_CODE]`` as an ADC does, and the number
    of samples that were beyond.

    >>> clip_full_scale(np.array([0.5, 1.5, -2.0]))
    (array([ 0.5       ,  0.99999988, -1.        ]), 2)
    """
    over = int(np.count_nonzero((x > TOP_CODE) | (x < -1.0)))
    return np.clip(x, -1.0, TOP_CODE), over


@dataclass(frozen=True)
class Target:
    """A target: its trajectory and target strength (dB re 1 m²)."""

    trajectory: Trajectory
    target_strength_db: float = 0.0


class _EchoGain:
    """Path gain hook (see the module docstring) for one echo path: spreading and
    absorption on both legs, the projector's response in the direction the path leaves it
    and the hydrophone's in the direction it arrives from."""

    #: Its value is a function of the solved geometry (leg lengths, positions), not of the
    #: times: a still path's gain is the same at every time (see ``GridEcho``).
    from_geometry = True

    def __init__(
        self,
        amplitude: float,
        path: EchoPath,
        tx: Transducer | None,
        rx: Transducer | None,
        absorption_db_per_km: float,
    ) -> None:
        self.amplitude, self.path = amplitude, path
        self.tx = None if tx is None or tx.omni else tx
        self.rx = None if rx is None or rx.omni else rx
        self.absorption = absorption_db_per_km

    def __call__(self, sol: PathSolution) -> FloatArray:
        r1, r2 = sol.leg_lengths_m
        if np.any(r1 <= 0) or np.any(r2 <= 0):
            raise ConfigError("target range", 0.0, "> 0 m", "a target sits on the transducer")
        g = self.amplitude / (r1 * r2)
        if self.absorption > 0:
            g = g * 10.0 ** (-self.absorption * (r1 + r2) / 20000.0)
        if (self.tx is not None or self.rx is not None) and sol.t_bounce_s is not None:
            p = self.path
            if sol.positions_m is not None:  # where the solve found them: no new queries
                tx_at, at, rx_at = sol.positions_m
            else:
                at = p.target.position(sol.t_bounce_s)
                tx_at, rx_at = p.tx.position(sol.t_emit_s), p.rx.position(sol.t_rx_s)
            if self.tx is not None:
                g = g * self.tx.response((at - tx_at) * p.tx_sign)
            if self.rx is not None:
                g = g * self.rx.response((at - rx_at) * p.rx_sign)
        return np.asarray(g, dtype=np.float64)


@dataclass(frozen=True)
class DirectBlast:
    """Transmitter-to-receiver leakage: a one-way path over ``separation_m`` (m, > 0) with
    spherical spreading and ``coupling_db`` (dB) on top: ``A · 10^(coupling/20) / r``."""

    coupling_db: float = 0.0
    separation_m: float = 0.1

    def __post_init__(self) -> None:
        if not (math.isfinite(self.separation_m) and self.separation_m > 0):
            raise ConfigError("direct_blast.separation_m", self.separation_m, "> 0 m")


@dataclass
class Channel:
    """The composed channel; see the module docstring.

    ``sonar`` is the monostatic transducer's trajectory; ``tx_beam`` / ``rx_beam`` the
    projector's and the hydrophone's directivity (``None`` = omni), applied per path
    direction; ``tank``/``image_order`` add the image paths (per round trip, see
    :mod:`~sim_devices.acoustics.tank`); ``tank_echoes`` adds the tank's own echoes and
    late tail (:mod:`~sim_devices.acoustics.tank_response`, needs a sonar at rest);
    ``components`` (filled by :meth:`read_components`) are pressure streams in µPa.
    """

    waveform: TransmitWaveform
    fs_hz: float
    sonar: Trajectory
    source_level_db: float
    sound_speed_mps: float
    targets: Sequence[Target] = ()
    receiver: Receiver = field(default_factory=Receiver)
    tx_beam: Transducer | None = None
    rx_beam: Transducer | None = None
    absorption_db_per_km: float = 0.0
    tank: Tank | None = None
    image_order: int = 0
    tank_echoes: TankEchoSettings | None = None
    direct_blast: DirectBlast | None = None
    reverberation: VolumeReverberation | None = None
    noise: ShapedNoiseGenerator | None = None
    noise_scale: float = 1.0
    position: int = 0
    #: Received samples clipped so far (the ADC's input beyond full scale).
    clipped_samples: int = 0

    def __post_init__(self) -> None:
        self.amplitude = source_amplitude(self.source_level_db)
        self._echoes: list[GridEcho] = []
        for tgt in self.targets:
            a = self.amplitude * 10.0 ** (tgt.target_strength_db / 20.0)
            for path in echo_paths(self.sonar, tgt.trajectory, self.tank, self.image_order):
                gain = _EchoGain(
                    a * path.gain, path, self.tx_beam, self.rx_beam, self.absorption_db_per_km
                )
                solved = TwoWayPath(path.tx, path.target, path.rx, self.sound_speed_mps)
                self._echoes.append(GridEcho(self.waveform, solved, self.fs_hz, gain=gain))
        self._blast: GridEcho | None = None
        if self.direct_blast is not None:
            db = self.direct_blast
            tx = Offset(self.sonar, (0.0, 0.0, db.separation_m))
            a = self.amplitude * 10.0 ** (db.coupling_db / 20.0) / db.separation_m
            self._blast = GridEcho(
                self.waveform, OneWayPath(tx, self.sonar, self.sound_speed_mps), self.fs_hz,
                amplitude=a,
            )  # fmt: skip
        self._tank: TankEchoes | None = None
        if self.tank_echoes is not None:
            self._tank = self._build_tank_echoes(self.tank_echoes)
        self._echo_frames = _Frames(EchoBank(self._echoes).block)
        self._blast_frames = _Frames(EchoBank([self._blast] if self._blast else []).block)

    def _build_tank_echoes(self, settings: TankEchoSettings) -> TankEchoes:
        if self.tank is None:
            raise ConfigError("tank.own_echoes", True, "a [tank] to echo in", "give tank.size_m")
        if self.sonar.max_speed_mps != 0.0:
            raise ConfigError(
                "tank.own_echoes",
                True,
                "a sonar at rest (its tank response is one fixed impulse response)",
                "set sonar.velocity_mps to zero or turn tank.own_echoes off",
            )
        at = self.sonar.position(np.zeros(1))[0]
        h = tank_impulse_response(
            self.tank, at, at, self.sound_speed_mps, self.fs_hz, settings,
            tx=self.tx_beam, rx=self.rx_beam, absorption_db_per_km=self.absorption_db_per_km,
        )  # fmt: skip
        fs, waveform = self.fs_hz, self.waveform
        # Hops all of amplitude 1: s = 1 · cos Φ is cos Φ exactly, without evaluate()'s
        # second hop look-up.
        unit = isinstance(waveform, HopSchedule) and bool(np.all(waveform.amplitude == 1.0))

        def source(n0: int, count: int) -> FloatArray:
            if unit:  # the phase of instantaneous_phase(n / fs), bit for bit, compiled
                return np.cos(sample_phases(waveform, n0, count, fs))  # type: ignore[arg-type]
            n = np.arange(n0, n0 + count, dtype=np.int64)
            return np.asarray(waveform.evaluate(n / fs), dtype=np.float64)

        return TankEchoes(h, source, self.amplitude)

    def read_components(self, n_samples: int, *, clip: bool = True) -> dict[str, FloatArray]:
        """The next ``n_samples``: pressure of every component (µPa), the ADC input
        ``input_fs`` (full scale) and, with ``clip``, the ``received`` samples (clipped and
        counted). A simulated ADC that clips and counts itself reads with ``clip=False``."""
        if int(n_samples) != n_samples or n_samples < 0:
            raise ConfigError("n_samples", n_samples, "an integer >= 0")
        n, n0 = int(n_samples), int(self.position)
        parts = {"echo": self._echo_frames.read(n0, n) if self._echoes else np.zeros(n)}
        parts["direct"] = self._blast_frames.read(n0, n) if self._blast else np.zeros(n)
        parts["tank"] = self._tank.generate(n) if self._tank is not None else np.zeros(n)
        parts["reverberation"] = (
            self.reverberation.generate(n) if self.reverberation is not None else np.zeros(n)
        )
        parts["noise"] = (
            self.noise_scale * self.noise.generate(n) if self.noise is not None else np.zeros(n)
        )
        total = (
            parts["echo"] + parts["direct"] + parts["tank"] + parts["reverberation"]
            + parts["noise"]
        )  # fmt: skip
        parts["pressure"] = total
        parts["input_fs"] = self.receiver.to_full_scale(total)
        if clip:
            parts["received"], clipped = clip_full_scale(parts["input_fs"])
            self.clipped_samples += clipped
        self.position += n
        return parts

    def read(self, n_samples: int) -> FloatArray:
        """The next ``n_samples`` received ADC samples in ``[-1, 1)``, shape ``(n,)``."""
        return self.read_components(n_samples)["received"]

    def echo_power(self, target_index: int = 0, t_s: float = 0.0) -> float:
        """Mean-square pressure (µPa²) of a target's direct echo received at ``t_s`` (s)."""
        echo = self._echoes[target_index * self._paths_per_target()]
        sol = echo.path.solve(np.array([t_s]))
        g = float(echo.gain(sol)[0]) * echo.amplitude
        return g * g / 2.0

    def _paths_per_target(self) -> int:
        return len(self._echoes) // max(1, len(self.targets))


class _Frames:
    """Samples of a block renderer served from fixed frames of :data:`ECHO_FRAME` samples
    (frame ``k`` is samples ``k F … (k + 1) F − 1``): any chunking of the reads gives the same
    samples, and small reads cost a slice, not a render."""

    def __init__(self, render: Callable[[int, int], FloatArray]) -> None:
        self.render = render
        self._start = 0
        self._frame = np.zeros(0)

    def read(self, n0: int, count: int) -> FloatArray:
        out = np.empty(count)
        done = 0
        while done < count:
            m = n0 + done
            off = m - self._start
            if not 0 <= off < self._frame.shape[0]:
                self._start = (m // ECHO_FRAME) * ECHO_FRAME
                self._frame = self.render(self._start, ECHO_FRAME)
                off = m - self._start
            take = min(count - done, self._frame.shape[0] - off)
            out[done : done + take] = self._frame[off : off + take]
            done += take
        return out


def echo_level_db(
    source_level_db: float, range_m: float, target_strength_db: float, absorption_db_per_km: float
) -> float:
    """Echo level EL = SL − 2 TL + TS (dB re 1 µPa), TL = 20 log r + α r/1000 (monostatic)."""
    tl = 20.0 * math.log10(range_m) + absorption_db_per_km * range_m / 1000.0
    return source_level_db - 2.0 * tl + target_strength_db
