"""Shared signals for the GCAS tests: exact moving-target echoes plus seeded white noise."""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np
import pytest

from hil.estimation.base import Estimate, Receiver
from hil.estimation.gcas import GcasReceiver
from hil.signals.presets import check_design, get_preset
from hil.signals.schedule import HopSchedule
from sim_devices.acoustics.delay import TwoWayPath
from sim_devices.acoustics.echo import AnalyticEcho
from sim_devices.acoustics.trajectory import ConstantVelocity, Fixed, Trajectory
from sim_devices.acoustics.truth import HopTruth, hop_truth

C = 1500.0
FS = 100_000.0

EchoFactory = Callable[..., np.ndarray]


@functools.cache
def preset_schedule(preset: str, family: str = "random-cyclic") -> HopSchedule:
    """The schedule of ``preset`` and ``family``, one object per process: a schedule is
    immutable, and the receivers built from one object share what is derived from it (the
    refinement's codewords, made once: :class:`~hil.estimation.codewords.CodewordBook`;
    tests/estimation_gcas/test_codewords.py builds its own objects)."""
    return check_design(get_preset(preset).spec(family))


def att_schedule(family: str = "random-cyclic") -> HopSchedule:
    """The ``att`` preset schedule of ``family`` (:func:`preset_schedule`)."""
    return preset_schedule("att", family)


def echo_samples(
    schedule: HopSchedule,
    range_m: float,
    speed_mps: float,
    duration_s: float,
    *,
    snr_db: float | None = None,
    seed: int = 0,
    fs_hz: float = FS,
    c: float = C,
    amplitude: float = 1.0,
) -> np.ndarray:
    """Echo of a target at ``range_m`` (t = 0) closing at ``speed_mps``, plus white noise of
    per-sample SNR ``snr_db`` (echo power ``amplitude²/2`` over noise variance)."""
    path = TwoWayPath.monostatic(
        Fixed((0.0, 0.0, 0.0)), ConstantVelocity((range_m, 0.0, 0.0), (-speed_mps, 0.0, 0.0)), c
    )
    x = AnalyticEcho(schedule, path, fs_hz, amplitude=amplitude).block(
        0, int(round(duration_s * fs_hz))
    )
    if snr_db is not None:
        sigma = amplitude / np.sqrt(2.0) / 10 ** (snr_db / 20.0)
        x = x + np.random.default_rng(seed).normal(0.0, sigma, x.shape)
    return x


def trajectory_echo(
    schedule: HopSchedule, target: Trajectory, duration_s: float, snr_db: float, seed: int
) -> tuple[np.ndarray, list[HopTruth]]:
    """The echo of ``target`` (any trajectory; the sonar at rest at the origin) over
    ``duration_s`` (s) at :data:`FS`, plus white noise of per-sample SNR ``snr_db`` (unit
    echo amplitude; seeded by ``seed``), and the truth at each hop boundary
    (:func:`~sim_devices.acoustics.truth.hop_truth`)."""
    sonar = Fixed((0.0, 0.0, 0.0))
    path = TwoWayPath.monostatic(sonar, target, C)
    n = int(duration_s * FS)
    x = AnalyticEcho(schedule, path, FS).block(0, n)
    sigma = np.sqrt(0.5 * 10.0 ** (-snr_db / 10.0))
    x = x + np.random.default_rng(seed).normal(0.0, sigma, n)
    return x, hop_truth(schedule, sonar, target, C, n / FS, 0.2)


def on_boundary(estimate: Estimate, truth: dict[int, HopTruth]) -> HopTruth | None:
    """The truth (by hop index) of the boundary ``estimate`` belongs to: within 0.5 m and
    0.5 m/s of it (hil.evaluation.trials_scene's gates); None where it is false."""
    h = truth.get(estimate.hop_index + 1)
    if h is None or abs(estimate.range_m - h.range_m) >= 0.5:
        return None
    return h if abs(estimate.speed_mps - h.radial_speed_mps) < 0.5 else None


def true_range(range_m: float, speed_mps: float, t_tx: float, t_rx: float) -> float:
    """Range at the bounce instant ``(t_tx + t_rx)/2`` of a constant-velocity target, m."""
    return range_m - speed_mps * 0.5 * (t_tx + t_rx)


@pytest.fixture(scope="session")
def rc_schedule() -> HopSchedule:
    return att_schedule("random-cyclic")


def make_gcas(schedule: HopSchedule, m_hops: int = 10, **extra: object) -> GcasReceiver:
    """The GCAS receiver these tests use (30 m/s, 100 m) with ``extra`` options."""
    return GcasReceiver.from_options(
        schedule, FS, sound_speed_mps=C, max_speed_mps=30.0, max_range_m=100.0,
        m_hops=m_hops, **extra,
    )  # fmt: skip


def run_blocks(rx: Receiver, x: np.ndarray, block: int = 10_000) -> list[Estimate]:
    """``x`` through ``rx`` in blocks of ``block`` samples, then its flush."""
    out: list[Estimate] = []
    for i in range(0, x.shape[0], block):
        out += rx.process(x[i : i + block])
    return out + rx.flush()


#: The lone target of :func:`lone_target_two_stage`: range at t = 0 (m).
LONE_TARGET_R0_M = 60.0


@functools.cache
def lone_target_two_stage(speed_mps: float) -> tuple[np.ndarray, tuple[Estimate, ...]]:
    """A lone target at :data:`LONE_TARGET_R0_M` closing at ``speed_mps`` in white noise
    (random-cyclic ``att``, 0.8 s, 0 dB per-sample SNR, seed 1; shape ``(80 000,)``, read
    only) and the default receiver's estimates of it (two-stage search, no reverberation
    band), made once per process: test_gcas_receiver checks them against the truth and
    test_gcas_two_stage against the full search's."""
    schedule = att_schedule("random-cyclic")
    x = echo_samples(schedule, LONE_TARGET_R0_M, speed_mps, 0.8, snr_db=0.0, seed=1)
    x.flags.writeable = False
    rx = make_gcas(schedule, search="two-stage", reverb_speed_mps=0.0)
    return x, tuple(run_blocks(rx, x))


@functools.cache
def design_speed_target() -> tuple[tuple[Estimate, ...], tuple[Estimate, ...]]:
    """A target closing at 25 m/s from 60 m (random-cyclic ``att``, 0.8 s, 0 dB per-sample
    SNR, seed 1; the default band masks the ghost cells beside it): the default receiver's
    estimates with the refinement off, then on, made once per process: test_refine and
    test_reverb_band read the same runs."""
    schedule = att_schedule("random-cyclic")
    x = echo_samples(schedule, 60.0, 25.0, 0.8, snr_db=0.0, seed=1)
    raw = run_blocks(make_gcas(schedule, refine=False), x)
    return tuple(raw), tuple(run_blocks(make_gcas(schedule), x))


def block_edges(n: int, cut: int | str) -> list[int]:
    """Block edges over ``n`` samples: every ``cut`` samples, or 20 random cuts seeded with
    ``cut`` (given as ``"random-<seed>"``)."""
    if isinstance(cut, int):
        return [*range(0, n, cut), n]
    rng = np.random.default_rng(int(cut.split("-")[1]))
    return sorted({0, n, *rng.integers(1, n, 20).tolist()})


def count_calls(monkeypatch: pytest.MonkeyPatch, owner: type, name: str) -> list[int]:
    """Count the calls of method ``name`` of class ``owner`` for the rest of the test: the
    returned list's one item is the count so far (the method itself still runs)."""
    calls = [0]
    original = getattr(owner, name)

    def counted(self: object, *args: object, **kwargs: object) -> object:
        calls[0] += 1
        return original(self, *args, **kwargs)

    monkeypatch.setattr(owner, name, counted)
    return calls


def count_hits(estimates: list[Estimate], range_m: float, speed_mps: float) -> int:
    """How many of ``estimates`` lie within 0.5 m and 0.5 m/s of the target that was at
    ``range_m`` (m, at t = 0) moving at ``speed_mps`` (m/s, closing positive)."""
    return sum(
        abs(e.speed_mps - speed_mps) < 0.5
        and abs(e.range_m - true_range(range_m, speed_mps, e.t_tx_s, e.t_s)) < 0.5
        for e in estimates
    )
