"""Scenes beyond one target moving inside the span: the trial ``scene`` and its named scenes.

Each scene of :data:`~hil.evaluation.scenes.SCENES` is one of issue 26's: objects at rest or
slow, a target braking to rest or reversing through it, two targets (apart, crossing in range,
starting at one range, the second 10 dB weaker), a target faster than the span, one at the
preset's design speed and an opening one, a still wall 16 dB above a moving target, one 10 dB
above a target at its ghost's speed, and a still target with the reverberation band off.
:func:`scene_trial` synthesises it (every target's exact echo,
:class:`~sim_devices.acoustics.echo.AnalyticEcho`, at its own level; white noise at ``snr_db``;
volume reverberation from a sonar at rest where ``srr_db`` is a number), runs the receiver as
``hil estimate`` builds it (``receiver``: GCAS unless given, or one of its input stages of
:data:`SCENE_RECEIVERS`; ``gcas-bg`` on the scene's empty water, captured first:
:func:`empty_water_background`; on ``att``, M = 10, ``max_speed_mps`` 30 m/s unless the scene or
the parameters say otherwise) and scores every estimate against every target's truth per hop
boundary:

- an estimate **belongs** to a target when its boundary's truth (hop index ``h + 1``, receive
  time within half a hop) is within :data:`~hil.evaluation.scenes.GATE_M` in range and
  :data:`~hil.evaluation.scenes.GATE_MPS` in speed;
  one that belongs to no target is **false**, a second one of a boundary already detected a
  **duplicate** (neither is a detection);
- a target's **expected** boundaries are those received in ``[warmup_s, duration_s − 2
  T_h)`` at a speed the receiver promises to measure: inside the span, and past the
  reverberation band's clutter speed by one Doppler resolution of a hop (the band's edge
  hypotheses hold a target up to there; with the band off, every speed); ``pd`` of a target is
  its detected expected boundaries over its expected ones;
- range and speed errors (m, m/s, estimate − truth) of every estimate that belongs to a
  target, per target; the notices the receiver said (an echo beyond the span, clutter) and the
  track ids its estimates carry.

The report (:mod:`hil.evaluation.report_scene`) pools the trials of each point. Shipped sweep:
``hil sweep scenes`` (``hil/data/sweeps/scenes.toml``); the figures of its full run are in
docs/results.md, "Scenes: several targets, objects at rest, braking, beyond the span".

hil must not import ``sim_devices`` at module level: the simulator is imported inside the
trial function.
"""

from __future__ import annotations

import json
import math
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from hil.errors import ConfigError
from hil.estimation.base import CountsRefusals, Estimate, SaysNotices
from hil.estimation.reverb_band import doppler_resolution_mps, resolve_reverb_speed
from hil.evaluation.gospa import gospa, track_switches
from hil.evaluation.registry import Params
from hil.evaluation.report_scene import write_scene_report
from hil.evaluation.scenes import GATE_M, GATE_MPS, GOSPA_CUTOFF_M, SCENES
from hil.evaluation.trials_ch6 import (
    RECEIVER_DEFAULTS,
    RECEIVER_KEYS,
    check_receiver,
    make_receiver,
    noise_sigma,
    point_schedule,
    preset_spec,
    volume_reverberation,
)

#: Parameters of :func:`scene_trial` and their defaults (units in the names): ``srr_db``
#: "off" (no reverberation) or dB; ``max_speed_mps``, ``reverb_speed_mps`` and
#: ``reverb_min_range_m`` left at None take the scene's value, else 30 m/s, "auto" and 5 m.
SCENE_DEFAULTS: dict[str, Any] = {
    "scene": "two-apart",
    "snr_db": 0.0,
    "srr_db": "off",
    "m_hops": 10,
    "max_speed_mps": None,
    "reverb_speed_mps": None,
    "reverb_min_range_m": None,
    "duration_s": 2.0,
    "warmup_s": 0.15,
    "receiver": "gcas",
    "receiver_options": {},
}
#: Receivers a scene runs: the GCAS family (the other receivers report one estimate per hop).
#: ``gcas-bg`` is given the scene's empty water, captured by the trial as the calibration
#: routine captures a tank's (:func:`empty_water_background`).
SCENE_RECEIVERS = ("gcas", "gcas-mti", "gcas-still", "gcas-bg")
#: ``gcas-bg``'s settings in a scene unless ``receiver_options`` gives them: the scene's
#: reverberation band and GCAS's own readout (the refinement, the peak: a scene's echoes
#: arrive on one path, with no images for a first-arrival readout to find).
SCENE_BG_OPTIONS: dict[str, Any] = {"refine": True, "range_readout": "peak"}


def _number(key: str, value: Any, lo: float, hi: float) -> float:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or not lo <= value <= hi:
        raise ConfigError(key, value, f"a finite number in {lo:g} .. {hi:g}")
    return float(value)


def _settings(params: Params) -> dict[str, Any]:
    """The trial's settings: defaults, the scene's, then the parameters given."""
    for key, value in params.items():
        if key not in SCENE_DEFAULTS:
            raise ConfigError(key, value, f"a parameter of scene: {', '.join(SCENE_DEFAULTS)}")
    p = {**SCENE_DEFAULTS, **params}
    if p["scene"] not in SCENES:
        raise ConfigError(
            "scene", p["scene"], f"one of {', '.join(SCENES)}", "see hil.evaluation.scenes"
        )
    scene = SCENES[p["scene"]]
    own = {"max_speed_mps": (scene.max_speed_mps, 30.0),
           "reverb_speed_mps": (scene.reverb_speed_mps, "auto"),
           "reverb_min_range_m": (scene.reverb_min_range_m, 5.0)}  # fmt: skip
    for key, (scene_value, fallback) in own.items():
        if p[key] is None:
            p[key] = fallback if scene_value is None else scene_value
    return p


def validate_scene_params(params: Params) -> None:
    """Check one grid point of :func:`scene_trial` (the receiver is built, no samples).

    >>> validate_scene_params({"scene": "three-apart"})
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: scene = 'three-apart' is not allowed: must be one of still, ...
    """
    p = _settings(params)
    _number("snr_db", p["snr_db"], -100.0, 200.0)
    srr = p["srr_db"]
    if srr != "off" and not (
        isinstance(srr, (int, float)) and not isinstance(srr, bool) and -100.0 <= srr <= 200.0
    ):
        raise ConfigError("srr_db", srr, '"off" (no reverberation) or a number in -100 .. 200 dB')
    duration = _number("duration_s", p["duration_s"], 0.2, 60.0)
    warmup = _number("warmup_s", p["warmup_s"], 0.0, 60.0)
    _number("reverb_min_range_m", p["reverb_min_range_m"], 0.1, 100.0)
    if warmup >= duration - 0.1:
        raise ConfigError("warmup_s", warmup, f"< duration_s − 0.1 s = {duration - 0.1:g} s")
    for t in SCENES[p["scene"]].targets:
        if float(np.min(t.range_at(np.linspace(0.0, duration, 64)))) < 2.0:
            raise ConfigError(
                "duration_s",
                duration,
                "a duration in which every target stays beyond 2 m",
                f"scene {p['scene']}'s target from {t.range_m} m comes nearer",
            )
    if p["receiver"] not in SCENE_RECEIVERS:
        raise ConfigError(
            "receiver",
            p["receiver"],
            f"one of {', '.join(SCENE_RECEIVERS)}",
            "a scene runs the GCAS receivers",
        )
    if not isinstance(p["receiver_options"], dict):
        raise ConfigError(
            "receiver_options", p["receiver_options"], f"a table of {p['receiver']} options"
        )
    if p["receiver"] == "gcas-bg":
        if "background" in p["receiver_options"]:
            raise ConfigError(
                "receiver_options.background",
                p["receiver_options"]["background"],
                "left out: a scene captures gcas-bg's background from its own empty water",
                "remove it (hil estimate and tank runs take a captured one)",
            )
        schedule, _, _ = _schedule_of(p)
        period = schedule.period_samples(float(schedule.params["fs_hz"]))
        with _background_file(np.zeros(period)) as path:
            _receiver(_with_background(p, path))
        return
    ch6 = _receiver_params(p)
    check_receiver(json.dumps({k: ch6[k] for k in RECEIVER_KEYS}, sort_keys=True))


def _receiver_params(p: dict[str, Any]) -> dict[str, Any]:
    """The scene's receiver as a chapter-6 trial's parameters (the GCAS family on ``att``;
    the reverberation band ``reverb_speed_mps`` and ``receiver_options`` go to it)."""
    name = p["receiver"]
    return {**RECEIVER_DEFAULTS, "receiver": name, "m_hops": p["m_hops"],
            "max_speed_mps": p["max_speed_mps"], "reverb_speed_mps": p["reverb_speed_mps"],
            "receiver_options": {name: p["receiver_options"]}}  # fmt: skip


def _schedule_of(p: dict[str, Any]) -> tuple[Any, float, dict[str, Any]]:
    """The scene's schedule, sound speed (m/s) and receiver as a chapter-6 trial's
    parameters."""
    ch6 = _receiver_params(p)
    return (
        point_schedule(ch6),
        float(preset_spec(ch6["preset"], ch6["family"]).sound_speed_mps),
        ch6,
    )


def _receiver(p: dict[str, Any]) -> Any:
    schedule, c, ch6 = _schedule_of(p)
    return make_receiver(ch6, schedule, c), schedule, c, ch6


def _with_background(p: dict[str, Any], path: str) -> dict[str, Any]:
    """The ``gcas-bg`` settings ``p`` with the background at ``path`` (:data:`SCENE_BG_OPTIONS`
    and the scene's reverberation band unless its ``receiver_options`` give them)."""
    band = {"reverb_speed_mps": p["reverb_speed_mps"]}
    options = {**SCENE_BG_OPTIONS, **band, **p["receiver_options"], "background": path}
    return {**p, "receiver_options": options}


@contextmanager
def _background_file(background: NDArray[np.float64]) -> Iterator[str]:
    """``background`` saved as the ``.npy`` file ``gcas-bg`` reads, removed after use."""
    with tempfile.TemporaryDirectory(prefix="scene-bg-") as folder:
        path = str(Path(folder) / "background.npy")
        np.save(path, background)
        yield path


def empty_water_background(
    schedule: Any, fs: float, c: float, ch6: dict[str, Any], p: dict[str, Any],
    reverb_seed: int | None, rng: np.random.Generator,
) -> NDArray[np.float64]:  # fmt: skip
    """The scene's water without its targets, as the calibration routine captures a tank's
    (:mod:`hil.experiments.calibration.background`): the same reverberation (its scatterers
    drawn from ``reverb_seed``; None for none) and noise of its own from ``rng`` at the scene's
    SNR over ``SETTLE_PERIODS + BACKGROUND_PERIODS`` still periods, averaged over the last
    ``BACKGROUND_PERIODS``: shape ``(P,)``, P the still period (samples at ``fs``, Hz)."""
    from hil.estimation.still_period import still_period
    from hil.experiments.calibration.background import (
        BACKGROUND_PERIODS,
        SETTLE_PERIODS,
        average_periods,
    )

    period, sign = still_period(schedule, schedule.period_samples(fs))
    n = (SETTLE_PERIODS + BACKGROUND_PERIODS) * period
    water = rng.normal(0.0, noise_sigma(float(p["snr_db"])), n)
    if reverb_seed is not None:
        reverb = {**ch6, "reverb_min_range_m": float(p["reverb_min_range_m"])}
        water += volume_reverberation(schedule, fs, c, reverb, float(p["srr_db"]), reverb_seed, n)
    skip = SETTLE_PERIODS * period
    return average_periods(water[skip:], period, skip, sign)


def _expected_speed_mps(schedule: Any, c: float, p: dict[str, Any]) -> float:
    """The least speed (m/s) at which a boundary is expected to be detected (module
    docstring): 0 with the band off, else the band's clutter speed plus one Doppler
    resolution of a hop."""
    tones = np.asarray(schedule.tones_hz, dtype=np.float64)
    band = resolve_reverb_speed(
        p["reverb_speed_mps"], tones, schedule.hop_s, c, float(p["max_speed_mps"])
    )
    if band == 0.0:
        return 0.0
    return band + doppler_resolution_mps(tones, schedule.hop_s, c)


def scene_trial(params: Params, seed: np.random.SeedSequence) -> dict[str, Any]:
    """One scene (module docstring): synthesise, run the receiver, score per target.

    Returns, per target ``i`` (lists in the scene's order): ``expected`` and ``detected``
    boundaries, ``range_errors_m`` and ``speed_errors_mps`` (lists of lists); and
    ``n_false``, ``n_duplicate``, ``n_hops`` (hops in the scored window), ``beyond_span_said``
    and ``clutter_said`` (notices), ``refused_REASON`` (detections refused, by the reasons of
    :data:`~hil.estimation.base.REFUSAL_REASONS`), ``track_ids`` (the distinct
    track ids of the estimates that belong to each target, -1 for none yet),
    ``false_examples`` (up to five ``[t_s, range_m, speed_mps]``), the GOSPA sums of
    :func:`scene_gospa` and ``receiver_cpu_s``. ``tests/evaluation/test_evaluation_scene_sweep.py``
    runs seeded scenes.
    """
    import time

    from sim_devices.acoustics.delay import TwoWayPath
    from sim_devices.acoustics.echo import AnalyticEcho
    from sim_devices.acoustics.trajectory import Fixed
    from sim_devices.acoustics.truth import hop_truth

    validate_scene_params(params)
    p = _settings(params)
    scene = SCENES[p["scene"]]
    with_bg = p["receiver"] == "gcas-bg"
    if with_bg:  # built once its background is captured, below
        schedule, c, ch6 = _schedule_of(p)
    else:
        receiver, schedule, c, ch6 = _receiver(p)
    fs = float(schedule.params["fs_hz"])
    rng = np.random.default_rng(seed)
    duration = float(p["duration_s"])
    n = int(round(duration * fs))
    sonar = Fixed((0.0, 0.0, 0.0))
    x = rng.normal(0.0, noise_sigma(float(p["snr_db"])), n)
    truths = []
    max_delay = 2.0 * (float(ch6["max_range_m"]) + 10.0) / c
    for target in scene.targets:
        trajectory = target.trajectory()
        path = TwoWayPath.monostatic(sonar, trajectory, c)
        gain = 10.0 ** (target.level_db / 20.0)
        x += gain * AnalyticEcho(schedule, path, fs).block(0, n)
        truths.append(hop_truth(schedule, sonar, trajectory, c, duration, max_delay))
    reverb_seed = None
    if p["srr_db"] != "off":
        reverb = {**ch6, "reverb_min_range_m": float(p["reverb_min_range_m"])}
        reverb_seed = int(rng.integers(2**31))
        x += volume_reverberation(schedule, fs, c, reverb, float(p["srr_db"]), reverb_seed, n)
    if with_bg:
        background = empty_water_background(schedule, fs, c, ch6, p, reverb_seed, rng)
        with _background_file(background) as bg_file:
            receiver = _receiver(_with_background(p, bg_file))[0]
    start = time.process_time()
    estimates = list(receiver.process(x)) + list(receiver.flush())
    cpu = time.process_time() - start
    window = (float(p["warmup_s"]), duration - 2.0 * schedule.hop_s)
    out = score_scene(
        estimates, truths, window=window, hop_s=schedule.hop_s,
        min_speed_mps=_expected_speed_mps(schedule, c, p), max_speed_mps=float(p["max_speed_mps"]),
    )  # fmt: skip
    notices = [n.to_dict()["notice"] for n in receiver.notices()] if isinstance(
        receiver, SaysNotices
    ) else []  # fmt: skip
    out.update(
        beyond_span_said=sum(kind == "beyond_span" for kind in notices),
        clutter_said=sum(kind == "clutter" for kind in notices),
        receiver_cpu_s=cpu,
    )
    if isinstance(receiver, CountsRefusals):
        out.update({f"refused_{reason}": count for reason, count in receiver.refusals().items()})
    return out


def score_scene(
    estimates: list[Estimate],
    truths: list[list[Any]],
    *,
    window: tuple[float, float],
    hop_s: float,
    min_speed_mps: float,
    max_speed_mps: float,
) -> dict[str, Any]:
    """Score ``estimates`` against each target's truth per boundary (``truths[i]``: its
    :class:`~sim_devices.acoustics.truth.HopTruth` list) in ``window`` (s, receive times);
    expected boundaries at ``min_speed_mps <= |speed| <= max_speed_mps`` (m/s). The fields
    of :func:`scene_trial`'s result (module docstring for the rules).

    >>> from types import SimpleNamespace as NS
    >>> truth = [[NS(hop_index=k, t_rx_s=0.01 * k, range_m=40.0, radial_speed_mps=5.0)
    ...           for k in range(1, 11)]]
    >>> est = [NS(hop_index=k - 1, t_s=0.01 * k, range_m=40.1, speed_mps=5.0, track_id=0)
    ...        for k in (2, 3, 3)] + [NS(hop_index=4, t_s=0.05, range_m=45.0, speed_mps=5.0,
    ...                                   track_id=-1)]
    >>> s = score_scene(est, truth, window=(0.015, 0.1), hop_s=0.01, min_speed_mps=1.0,
    ...                 max_speed_mps=30.0)
    >>> s["expected"], s["detected"], s["n_duplicate"], s["n_false"], s["n_hops"]
    ([8], [2], 1, 1, 8)
    >>> s["gospa_missed"], s["gospa_false"], s["gospa_pairs"], s["track_switches"]
    (6, 2, 2, 0)
    """
    t0, t1 = window
    by_target = [{h.hop_index: h for h in truth} for truth in truths]
    expected = [
        sum(t0 <= h.t_rx_s < t1 and min_speed_mps <= abs(h.radial_speed_mps) <= max_speed_mps
            for h in truth)
        for truth in truths
    ]  # fmt: skip
    seen: list[set[int]] = [set() for _ in truths]
    r_err: list[list[float]] = [[] for _ in truths]
    v_err: list[list[float]] = [[] for _ in truths]
    tracks: list[set[int]] = [set() for _ in truths]
    n_false = n_duplicate = 0
    false_examples: list[list[float]] = []
    for e in estimates:
        if not t0 <= e.t_s < t1:
            continue
        owner = _owner(e, by_target, hop_s)
        if owner is None:
            n_false += 1
            if len(false_examples) < 5:
                false_examples.append([round(e.t_s, 4), round(e.range_m, 3), round(e.speed_mps, 3)])
            continue
        i, h = owner
        if h.hop_index in seen[i]:
            n_duplicate += 1
            continue
        seen[i].add(h.hop_index)
        r_err[i].append(round(float(e.range_m - h.range_m), 6))
        v_err[i].append(round(float(e.speed_mps - h.radial_speed_mps), 5))
        tracks[i].add(int(e.track_id))
    detected = [
        sum(t0 <= by[k].t_rx_s < t1 and min_speed_mps <= abs(by[k].radial_speed_mps)
            <= max_speed_mps for k in s)
        for by, s in zip(by_target, seen, strict=True)
    ]  # fmt: skip

    def is_expected(h: Any) -> bool:
        return t0 <= h.t_rx_s < t1 and min_speed_mps <= abs(h.radial_speed_mps) <= max_speed_mps

    inside = [e for e in estimates if t0 <= e.t_s < t1]
    boundaries = {h.hop_index for truth in truths for h in truth if t0 <= h.t_rx_s < t1}
    return {
        **scene_gospa(inside, by_target, is_expected, hop_s, boundaries),
        "expected": expected,
        "detected": detected,
        "range_errors_m": r_err,
        "speed_errors_mps": v_err,
        "track_ids": [sorted(t) for t in tracks],
        "n_false": n_false,
        "n_duplicate": n_duplicate,
        "n_hops": int(round((t1 - t0) / hop_s)),
        "false_examples": false_examples,
    }


def scene_gospa(
    estimates: list[Any],
    by_target: list[dict[int, Any]],
    is_expected: Callable[[Any], bool],
    hop_s: float,
    boundaries: set[int],
) -> dict[str, float | int]:
    """GOSPA (:mod:`hil.evaluation.gospa`, cut-off
    :data:`~hil.evaluation.scenes.GOSPA_CUTOFF_M`, order 2, speed weighed 1 s) at each
    transmit boundary ``h``: the expected targets' truths there (each target's boundary
    ``h``, ``by_target[i][h]``, where ``is_expected``) against the estimates of that boundary
    (``hop_index + 1 == h``), less those within the gates of a truth not expected (a target
    in the band reported: right, not false). Sums over the
    ``boundaries`` (the scored window's, whether a target is expected there or not) and any
    other an estimate names: ``gospa_sum_m2`` (``Σ d²``), ``gospa_times`` (their count),
    ``gospa_localisation_m2`` and ``gospa_pairs`` (the assigned pairs' ``Σ d²``
    and count), ``gospa_missed``, ``gospa_false``; and ``track_switches``
    (:func:`~hil.evaluation.gospa.track_switches` over the confirmed tracks' ids)."""
    by_boundary: dict[int, list[Any]] = {}
    for e in estimates:
        owner = _owner(e, by_target, hop_s)
        if owner is not None and not is_expected(owner[1]):
            continue
        by_boundary.setdefault(e.hop_index + 1, []).append(e)
    truth_at = set(boundaries) | set(by_boundary)
    sums = {"gospa_sum_m2": 0.0, "gospa_times": len(truth_at), "gospa_localisation_m2": 0.0,
            "gospa_pairs": 0, "gospa_missed": 0, "gospa_false": 0}  # fmt: skip
    labels: list[list[int | None]] = []
    for h in sorted(truth_at):
        targets = [i for i, by in enumerate(by_target) if h in by and is_expected(by[h])]
        ests = by_boundary.get(h, [])
        g = gospa(
            [[by_target[i][h].range_m, by_target[i][h].radial_speed_mps] for i in targets],
            [[e.range_m, e.speed_mps] for e in ests],
            cutoff=GOSPA_CUTOFF_M,
        )
        sums["gospa_sum_m2"] += g.distance**2
        sums["gospa_localisation_m2"] += g.localisation
        sums["gospa_pairs"] += len(g.pairs)
        sums["gospa_missed"] += g.missed
        sums["gospa_false"] += g.false
        row: list[int | None] = [None] * len(by_target)
        for k, j in g.pairs:
            track = int(ests[j].track_id)
            row[targets[k]] = track if track >= 0 else None
        labels.append(row)
    return {**sums, "track_switches": track_switches(labels)}


def _owner(e: Any, by_target: list[dict[int, Any]], hop_s: float) -> tuple[int, Any] | None:
    """The target (index, its boundary's truth) an estimate belongs to, nearest in range
    among those within the gates; None for none."""
    best: tuple[float, int, Any] | None = None
    for i, by in enumerate(by_target):
        h = by.get(e.hop_index + 1)
        if h is None or abs(e.t_s - h.t_rx_s) >= hop_s / 2:
            continue
        dr = abs(e.range_m - h.range_m)
        near = dr <= GATE_M and abs(e.speed_mps - h.radial_speed_mps) <= GATE_MPS
        if near and (best is None or dr < best[0]):
            best = (dr, i, h)
    return None if best is None else (best[1], best[2])


scene_trial.validate_params = validate_scene_params  # type: ignore[attr-defined]
scene_trial.write_report = write_scene_report  # type: ignore[attr-defined]
