"""PNG diagnostics of a waveform: spectrogram, time–frequency occupancy, ambiguity functions.

Each ``*_figure`` function returns a :class:`matplotlib.figure.Figure` (shown inline in a
notebook); each ``plot_*`` saves one to a file. matplotlib is imported inside the functions
and never told which backend to use (:mod:`hil.figures`), so importing this module costs
nothing and the caller's backend is left alone.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hil.figures import new_figure, save_figure
from hil.signals.ambiguity import AmbiguitySurface, narrowband_af, periodic_af, wideband_af
from hil.signals.random_cyclic import occupancy
from hil.signals.schedule import HopSchedule
from hil.signals.synthesis import synthesize

if TYPE_CHECKING:
    from matplotlib.figure import Figure


def plot_spectrogram(schedule: HopSchedule, fs_hz: float, duration_s: float, path: Path) -> Path:
    """Save :func:`spectrogram_figure` to ``path``."""
    return save_figure(spectrogram_figure(schedule, fs_hz, duration_s), path)


def spectrogram_figure(schedule: HopSchedule, fs_hz: float, duration_s: float) -> Figure:
    """Spectrogram (dB) of ``duration_s`` seconds of the waveform, zoomed on its band."""
    from scipy.signal import ShortTimeFFT
    from scipy.signal.windows import hann

    x = synthesize(schedule, fs_hz, duration_s)
    hop_guess = float(np.min(schedule.duration_s))
    nperseg = int(max(64, min(4096, 2 ** round(np.log2(max(hop_guess * fs_hz / 2, 64))))))
    stft = ShortTimeFFT(hann(nperseg, sym=False), hop=max(1, nperseg // 8), fs=fs_hz)
    s = stft.spectrogram(x)
    f = stft.f
    t = stft.t(x.shape[0])
    lo, hi = schedule.min_frequency_hz(), schedule.max_frequency_hz()
    margin = max(0.25 * (hi - lo), 500.0)
    keep = (f >= lo - margin) & (f <= hi + margin)
    db = 10 * np.log10(s[keep] / np.max(s) + 1e-12)
    fig, ax = new_figure(figsize=(9, 4.5), dpi=110)
    mesh = ax.pcolormesh(t, f[keep] / 1e3, db, shading="auto", vmin=-60, vmax=0, cmap="viridis")
    fig.colorbar(mesh, ax=ax, label="power (dB re max)")
    ax.set_xlim(0, duration_s)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("frequency (kHz)")
    ax.set_title(f"{schedule.family}: spectrogram ({nperseg}-sample Hann frames)")
    fig.tight_layout()
    return fig


def plot_occupancy(schedule: HopSchedule, path: Path) -> Path:
    """Save :func:`occupancy_figure` to ``path``."""
    return save_figure(occupancy_figure(schedule), path, dpi=110)


def occupancy_figure(schedule: HopSchedule) -> Figure:
    """The N_F × P time–frequency occupancy array of one period (one mark per hop)."""
    occ = occupancy(schedule.code, schedule.n_tones)
    fig, ax = new_figure(figsize=(max(4.0, 0.35 * occ.shape[1] + 2), 0.5 * occ.shape[0] + 2))
    ax.imshow(occ, origin="lower", aspect="auto", cmap="Greys", interpolation="nearest")
    ax.set_yticks(range(occ.shape[0]))
    ax.set_yticklabels([f"{f / 1e3:.3f}" for f in schedule.tones_hz])
    step = max(1, occ.shape[1] // 20)
    ax.set_xticks(range(0, occ.shape[1], step))
    ax.set_xlabel("hop in period")
    ax.set_ylabel("tone (kHz)")
    ax.set_title(f"{schedule.family}: occupancy, code {schedule.code.tolist()[:40]}", fontsize=8)
    fig.tight_layout()
    return fig


def plot_ambiguity(surface: AmbiguitySurface, title: str, path: Path) -> Path:
    """Save :func:`ambiguity_figure` to ``path``."""
    return save_figure(ambiguity_figure(surface, title), path)


def ambiguity_figure(surface: AmbiguitySurface, title: str) -> Figure:
    """|χ| in dB over delay and Doppler (shift in Hz, or scale α shown as speed-like axis)."""
    db = 20 * np.log10(np.maximum(surface.magnitude, 1e-6))
    fig, ax = new_figure(figsize=(8, 4.5), dpi=110)
    extent = (
        surface.delay_s[0] * 1e3,
        surface.delay_s[-1] * 1e3,
        float(surface.doppler[0]),
        float(surface.doppler[-1]),
    )
    im = ax.imshow(db, origin="lower", aspect="auto", extent=extent, vmin=-40, vmax=0, cmap="magma")
    fig.colorbar(im, ax=ax, label="|χ| (dB)")
    ax.set_xlabel("delay (ms)")
    ax.set_ylabel("Doppler shift (Hz)" if surface.doppler_kind == "shift_hz" else "time scale α")
    ax.set_title(title)
    fig.tight_layout()
    return fig


def write_diagnostics(
    schedule: HopSchedule,
    fs_hz: float,
    out_dir: Path,
    *,
    max_speed_mps: float,
    sound_speed_mps: float,
    duration_s: float | None = None,
) -> list[Path]:
    """Write every diagnostic PNG for ``schedule`` into ``out_dir``; return their paths.

    The AFs are computed at a reduced rate (at least 4× the highest frequency is not needed:
    the analytic signal only needs the band), keeping them quick for long periods.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    span = schedule.period_s if duration_s is None else min(duration_s, 2 * schedule.period_s)
    # Show a few periods of short codes, at most 2 s.
    spec_span = min(max(span, 4 * schedule.period_s), 2.0)
    paths.append(plot_spectrogram(schedule, fs_hz, spec_span, out_dir / "spectrogram.png"))
    paths.append(plot_occupancy(schedule, out_dir / "occupancy.png"))
    # Complex baseband-like rate: the analytic signal is sampled well above twice its band.
    bw = schedule.max_frequency_hz() - schedule.min_frequency_hz()
    af_fs = float(max(8.0 * max(bw, 1.0 / float(np.min(schedule.duration_s))), 4000.0))
    af_span = min(schedule.period_s, 0.5)
    max_delay = min(0.5 * af_span, 4.0 * float(np.min(schedule.duration_s)))
    f_top = schedule.max_frequency_hz()
    dmax = 2.0 * max_speed_mps / sound_speed_mps * f_top
    nb = narrowband_af(schedule, af_fs, af_span, max_delay, np.linspace(-dmax, dmax, 81))
    paths.append(
        plot_ambiguity(nb, f"{schedule.family}: narrowband AF", out_dir / "af_narrowband.png")
    )
    a_max = (sound_speed_mps + max_speed_mps) / (sound_speed_mps - max_speed_mps)
    wb = wideband_af(schedule, af_fs, af_span, max_delay, np.linspace(1 / a_max, a_max, 141))
    paths.append(plot_ambiguity(wb, f"{schedule.family}: wideband AF", out_dir / "af_wideband.png"))
    n_float = schedule.period_s * af_fs
    if abs(n_float - round(n_float)) < 1e-6 and schedule.period_s <= 2.0:
        paf = periodic_af(schedule, af_fs, np.linspace(-dmax, dmax, 81))
        paths.append(
            plot_ambiguity(
                paf, f"{schedule.family}: periodic AF (one period)", out_dir / "af_periodic.png"
            )
        )
    return paths
