"""The scene trial (``scene``), its scoring and report, and the shipped ``scenes`` sweep as
docs/results.md runs it."""

from __future__ import annotations

import csv
import functools
import json
import re
import shlex
from pathlib import Path
from types import SimpleNamespace as NS
from typing import Any

import numpy as np
import pytest

from hil.cli.main import main
from hil.errors import ConfigError
from hil.evaluation.report_scene import scene_rows
from hil.evaluation.scenes import SCENES, SceneTarget
from hil.evaluation.sweep_file import find_sweep_file, load_sweep_file
from hil.evaluation.trials_scene import (
    scene_trial,
    score_scene,
    validate_scene_params,
)

ROOT = Path(__file__).resolve().parents[2]
RESULTS_DOC = ROOT / "docs" / "results.md"


# ----------------------------------------------------------------------------- targets
def test_a_braking_target_comes_to_rest_and_stays() -> None:
    t = SceneTarget(40.0, 10.0, -10.0, stops=True)
    times = np.array([0.0, 0.5, 1.0, 1.5])
    np.testing.assert_allclose(t.closing_speed(times), [10.0, 5.0, 0.0, 0.0])
    np.testing.assert_allclose(t.range_at(times), [40.0, 36.25, 35.0, 35.0])


def test_a_reversing_target_goes_on_through_rest() -> None:
    t = SceneTarget(50.0, 8.0, -8.0)
    times = np.array([0.0, 1.0, 2.0])
    np.testing.assert_allclose(t.closing_speed(times), [8.0, 0.0, -8.0])
    np.testing.assert_allclose(t.range_at(times), [50.0, 46.0, 50.0])


# ----------------------------------------------------------------------------- scoring
def _truth(r: float, v: float, hops: range) -> list[NS]:
    return [NS(hop_index=k, t_rx_s=0.01 * k, range_m=r, radial_speed_mps=v) for k in hops]


def _est(k: int, r: float, v: float, track: int = 0) -> NS:
    return NS(hop_index=k - 1, t_s=0.01 * k, range_m=r, speed_mps=v, track_id=track)


def test_each_estimate_goes_to_the_nearest_target_within_the_gates() -> None:
    truths = [_truth(40.0, 10.0, range(1, 21)), _truth(40.3, 10.2, range(1, 21))]
    est = [
        _est(5, 40.05, 10.0),  # target 1 (0.05 m against 0.25 m)
        _est(5, 40.28, 10.1, track=1),  # target 2
        _est(6, 40.6, 10.0, track=1),  # 0.3 m from target 2, 0.6 m from 1: target 2's
        _est(7, 41.0, 10.0),  # 0.7 m from target 2: false
        _est(8, 40.0, 10.6),  # 0.6 m/s off target 1, 0.4 from target 2 but 0.3 m: target 2
        _est(9, 40.0, 11.0),  # 0.8 m/s from both: false
    ]
    s = score_scene(est, truths, window=(0.0, 0.2), hop_s=0.01, min_speed_mps=1.0,
                    max_speed_mps=30.0)  # fmt: skip
    assert s["detected"] == [1, 3] and s["n_false"] == 2 and s["n_duplicate"] == 0
    assert s["range_errors_m"] == [[0.05], [-0.02, 0.3, -0.3]]
    assert s["track_ids"] == [[0], [0, 1]]
    assert s["false_examples"] == [[0.07, 41.0, 10.0], [0.09, 40.0, 11.0]]


def test_boundaries_in_the_band_or_beyond_the_span_are_not_expected() -> None:
    truth = [NS(hop_index=k, t_rx_s=0.01 * k, range_m=40.0, radial_speed_mps=v)
             for k, v in ((1, 0.5), (2, 3.0), (3, 4.0), (4, 31.0), (5, -4.0))]  # fmt: skip
    s = score_scene([_est(1, 40.0, 0.5)], [truth], window=(0.0, 0.1), hop_s=0.01,
                    min_speed_mps=3.5, max_speed_mps=30.0)  # fmt: skip
    # The estimate at 0.5 m/s is right (no false one) but not an expected boundary.
    assert s["expected"] == [2] and s["detected"] == [0] and s["n_false"] == 0


def test_the_report_pools_each_targets_boundaries_over_the_trials() -> None:
    from hil.evaluation.spec import SweepSpec

    spec = SweepSpec("s", "scene", "m:t", 2, 0, {"scene": ["two-apart", "still"]})

    def res(expected: list[int], detected: list[int], false: int) -> dict[str, object]:
        return {"expected": expected, "detected": detected, "n_false": false, "n_duplicate": 1,
                "n_hops": 100, "range_errors_m": [[0.01, -0.03][:d] for d in detected],
                "speed_errors_mps": [[0.02] * d for d in detected], "beyond_span_said": 1,
                "clutter_said": 0}  # fmt: skip

    recs = [
        {"point": 0, "status": "ok", "result": res([50, 40], [50, 38], 1)},
        {"point": 0, "status": "ok", "result": res([50, 40], [48, 40], 3)},
        {"point": 1, "status": "ok", "result": res([0], [0], 2)},
        {"point": 1, "status": "failed", "error": "x"},
    ]
    two, still = scene_rows(spec, recs)
    assert two["pd_t1"] == pytest.approx(0.98) and two["pd_t2"] == pytest.approx(0.975)
    assert two["false_per_hop"] == 0.02 and two["n_duplicate"] == 2
    assert two["range_rmse_t1_m"] == pytest.approx(np.sqrt((0.01**2 + 0.03**2) / 2))
    assert two["beyond_span_said"] == 2
    assert np.isnan(still["pd_t1"]) and np.isnan(still["pd_t2"]) and still["n_failed"] == 1
    assert still["false_per_hop"] == 0.02


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("params", "field", "says"),
    [
        ({"scene": "three-apart"}, "scene", "one of still, slow-0.05"),
        ({"snr": 0.0}, "snr", "a parameter of scene: scene, snr_db"),
        ({"snr_db": "loud"}, "snr_db", "a finite number in -100 .. 200"),
        ({"srr_db": "on"}, "srr_db", '"off" (no reverberation) or a number in -100 .. 200 dB'),
        ({"srr_db": float("nan")}, "srr_db", '"off" (no reverberation) or a number'),
        ({"scene": "two-same-start", "duration_s": 5.0}, "duration_s",
         "every target stays beyond 2 m"),
        ({"warmup_s": 2.0}, "warmup_s", "< duration_s − 0.1 s"),
        ({"m_hops": 2}, "m_hops", "3..64"),
        ({"receiver": "gcas-tank"}, "receiver", "one of gcas, gcas-mti, gcas-still, gcas-bg"),
        ({"receiver": "gcas-bg", "receiver_options": {"range_readout": "centroid"}},
         "range_readout", "one of peak, first-arrival"),
        ({"receiver": "gcas-still", "receiver_options": {"still_periods": 0}}, "still_periods",
         "1 .. 64"),
    ],
)  # fmt: skip
def test_a_bad_parameter_is_refused_naming_it(
    params: dict[str, object], field: str, says: str
) -> None:
    with pytest.raises(ConfigError) as err:
        validate_scene_params(params)
    assert err.value.field == field and says in str(err.value)


# ----------------------------------------------------------------------------- the trial
@pytest.mark.slow
def test_two_targets_apart_at_minus_10_db_are_both_detected_each_its_own_track() -> None:
    out = scene_trial({"scene": "two-apart", "snr_db": -10.0, "duration_s": 1.0},
                      np.random.SeedSequence(5, spawn_key=(0, 0)))  # fmt: skip
    # Measured: 86 / 83 boundaries expected, every one detected, no false estimate; range
    # RMSE 3.6 / 4.0 mm.
    assert all(e >= 80 for e in out["expected"])
    assert out["detected"] == out["expected"] and out["n_false"] == 0
    assert [len(t) for t in out["track_ids"]] == [1, 1] and out["track_ids"][0] != out["track_ids"][
        1
    ]
    for errs in out["range_errors_m"]:
        assert np.sqrt(np.mean(np.square(errs))) < 0.01
    # GOSPA: every boundary of both paired, nothing missed or false, no track switch.
    assert out["gospa_pairs"] == sum(out["expected"]) and out["gospa_times"] >= 80
    assert (out["gospa_missed"], out["gospa_false"], out["track_switches"]) == (0, 0, 0)


@pytest.mark.slow
def test_a_target_beyond_the_span_is_said_and_not_reported() -> None:
    out = scene_trial({"scene": "beyond-span", "duration_s": 1.0},
                      np.random.SeedSequence(5, spawn_key=(1, 0)))  # fmt: skip
    assert out["expected"] == [0] and out["n_false"] == 0 and out["beyond_span_said"] == 1
    assert out["refused_beyond_span"] > 50


@pytest.mark.slow
def test_a_three_state_target_whose_ghost_is_in_the_band_is_said_and_not_reported(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Three-state (15 ms hops): 35 m/s with a 30 m/s span at -10 dB puts its only ghost at
    # -1.67 m/s, on the reverberation band's edge; nothing of it crosses the threshold
    # elsewhere, so the band's edge detections are where its source is looked for.
    import hil.evaluation.trials_scene as trials

    defaults = {**trials.RECEIVER_DEFAULTS, "family": "three-state"}
    monkeypatch.setattr(trials, "RECEIVER_DEFAULTS", defaults)
    params = {"scene": "beyond-span", "snr_db": -10.0, "duration_s": 2.0}
    for seed in (31000, 31001):
        out = scene_trial(params, np.random.SeedSequence(seed))
        assert out["expected"] == [0] and out["n_false"] == 0, seed
        assert out["beyond_span_said"] == 1, seed
        # Said at the second fit beyond the span, each of a detection refused as its ghost.
        assert out["refused_beyond_span"] >= 2, seed


@pytest.mark.slow
def test_the_band_off_scene_has_its_scatterers_from_1_m_and_expects_the_still_target() -> None:
    out = scene_trial({"scene": "still-band-off", "srr_db": 0.0, "duration_s": 1.0},
                      np.random.SeedSequence(5, spawn_key=(2, 0)))  # fmt: skip
    # With the band off every boundary of the target at rest is expected and measured.
    assert out["expected"][0] >= 80 and out["detected"][0] >= 0.9 * out["expected"][0]
    assert out["n_false"] <= 0.05 * out["n_hops"]


def test_the_empty_water_capture_is_the_scenes_reverberation_to_its_averaged_noise() -> None:
    # gcas-bg's background in a scene: the reverberation of the scene's scatterers over 16
    # still periods after 2, each with noise of its own, averaged (the calibration routine's
    # capture). What is left against the reverberation alone is that noise over 16 periods,
    # sigma/4, in the even periods and, sign flipped, in the odd ones (att's still period
    # changes sign).
    from hil.evaluation.trials_ch6 import noise_sigma, volume_reverberation
    from hil.evaluation.trials_scene import _schedule_of, _settings, empty_water_background

    p = _settings({"scene": "still-band-off", "snr_db": 0.0, "srr_db": 0.0})
    schedule, c, ch6 = _schedule_of(p)
    fs = float(schedule.params["fs_hz"])
    rng = np.random.default_rng(26)
    background = empty_water_background(schedule, fs, c, ch6, p, 12345, rng)
    period = background.size
    assert period == schedule.period_samples(fs) == 17_000
    reverb = volume_reverberation(
        schedule, fs, c, {**ch6, "reverb_min_range_m": 1.0}, 0.0, 12345, 3 * period
    )
    quiet = noise_sigma(0.0) / 4.0
    assert np.std(reverb[2 * period :]) > 3.0 * quiet  # measured 0.60 against 0.18
    assert np.std(background - reverb[2 * period :]) == pytest.approx(quiet, rel=0.03)
    assert np.std(background + reverb[period : 2 * period]) == pytest.approx(quiet, rel=0.03)
    alone = empty_water_background(schedule, fs, c, ch6, {**p, "srr_db": "off"}, None, rng)
    assert np.std(alone) == pytest.approx(quiet, rel=0.03)


# The band off in volume reverberation whose scatterers start at 1 m (still-band-off at
# 0 dB SRR; the sweep's own inputs, docs/results.md "Scenes"): a lone scatterer at 1.5-2 m is
# a point echo at rest as strong as the target at 40 m. Stage 1 keeps one still candidate per
# half hop, the scatterer's later boundary arriving with the target's wins it, and beside a
# still echo reported the other is not decided (Readout.decide_all): gcas reports the
# scatterer there and misses the target, which the second search then finds and drops as
# the still water's leftover. No test of one echo tells a lone scatterer at rest from a
# target at rest; the empty water does. Measured: gcas 67 of 183 boundaries, 90 false (the
# scatterer at 1.55 m), range RMSE 6.8 mm, at 0 dB; 98, 66 false (1.95 m), 25.4 mm at -10 dB;
# gcas-bg 183 of 183, none false, 1.5 and 3.2 mm (1.2 and 3.9 mm without reverberation).
@pytest.mark.slow
@pytest.mark.parametrize(("snr_db", "point", "rep", "rmse_max_m"),
                         [(0.0, 53, 3, 0.002), (-10.0, 55, 2, 0.005)])  # fmt: skip
def test_a_still_target_beside_a_lone_still_scatterer_is_kept_against_the_empty_water(
    snr_db: float, point: int, rep: int, rmse_max_m: float
) -> None:
    params = {"scene": "still-band-off", "snr_db": snr_db, "srr_db": 0.0}
    seed = np.random.SeedSequence(2626, spawn_key=(point, rep))
    gcas = scene_trial(params, seed)
    bg = scene_trial({**params, "receiver": "gcas-bg"}, seed)
    assert gcas["expected"] == bg["expected"] == [183]
    assert gcas["detected"][0] <= 0.6 * 183 and gcas["n_false"] >= 0.3 * gcas["n_hops"]
    assert all(1.4 <= r <= 2.1 and abs(v) <= 0.25 for _, r, v in gcas["false_examples"])
    assert bg["detected"] == [183] and bg["n_false"] == 0
    errors = np.asarray(bg["range_errors_m"][0])
    assert float(np.sqrt(np.mean(errors**2))) <= rmse_max_m


@pytest.mark.slow
def test_every_scene_of_the_shipped_sweep_is_a_known_scene_and_valid() -> None:
    spec = load_sweep_file(find_sweep_file("scenes"))
    assert sorted(spec.grid["scene"]) == sorted(SCENES)
    for point in range(spec.n_points):
        validate_scene_params({**spec.fixed, **spec.point_values(point)})


# ----------------------------------------------------------------------------- as documented
def _documented_quick_command() -> list[str]:
    """``hil sweep scenes ... --quick`` as docs/results.md writes it (the hil word dropped)."""
    lines = [
        line.split("#", 1)[0].strip()
        for line in RESULTS_DOC.read_text(encoding="utf-8").splitlines()
        if re.match(r"^hil sweep scenes .*--quick", line)
    ]
    assert len(lines) == 1, lines
    return shlex.split(lines[0])[1:]


@pytest.mark.slow
def test_the_documented_quick_scene_sweep_runs_and_reports(tmp_path: Path) -> None:
    args = _documented_quick_command()
    out = tmp_path / "scenes"
    args[args.index("--out") + 1] = str(out)
    assert main([*args, "--quiet"]) == 0
    records = [json.loads(line) for line in (out / "results.jsonl").read_text().splitlines()]
    by_scene = {r["params"]["scene"]: r["result"] for r in records}
    assert sorted(by_scene) == ["still", "two-apart"]
    two = by_scene["two-apart"]
    assert two["detected"] == two["expected"] and two["n_false"] == 0
    with (out / "scene_points.csv").open() as fh:
        rows = {r["scene"]: r for r in csv.DictReader(fh)}
    assert float(rows["two-apart"]["pd_t1"]) == 1.0
    assert float(rows["still"]["false_per_hop"]) == pytest.approx(
        by_scene["still"]["n_false"] / by_scene["still"]["n_hops"], abs=1e-6
    )
    for name in ("report.md", "figures/scene_rates.png", "summary.csv", "manifest.json"):
        assert (out / name).is_file(), name


@pytest.mark.slow
def test_the_weaker_target_under_still_reverberation_is_followed_on_its_own_lobe() -> None:
    # second-10db-weaker at -10 dB SNR with reverberation at 0 dB SRR: the weaker target is
    # 20 dB under the noise and 10 dB under the still reverberation, and the detector misses
    # a third of its boundaries. Measured (this seed, the first tried): gcas 161 of 182
    # boundaries, 1 false; gcas-still (the input less its still water) 169, 3 false. With a
    # followed fit's lobe decided anew on its own M hops beside the still water, and the
    # echo followed only while its latest fit reached 15 dB (before EchoFit.held): gcas
    # 127, gcas-still 146.
    params = {"scene": "second-10db-weaker", "snr_db": -10.0, "srr_db": 0.0}
    seed = np.random.SeedSequence(5, spawn_key=(2, 0))
    gcas = scene_trial({**params, "receiver": "gcas"}, seed)
    still = scene_trial({**params, "receiver": "gcas-still"}, seed)
    assert gcas["expected"] == still["expected"] == [185, 182]
    assert gcas["detected"][0] == still["detected"][0] == 185
    assert gcas["detected"][1] >= 0.85 * 182 and still["detected"][1] >= 0.9 * 182
    assert gcas["n_false"] <= 2 and still["n_false"] <= 4


@pytest.mark.slow
def test_a_target_10_db_weaker_at_minus_20_db_per_sample_is_followed_where_undetected() -> None:
    # second-10db-weaker at -10 dB SNR without reverberation (scenes.toml's point, seed 0):
    # the weaker target, 20 dB under the noise, is detected at 0.89 of its boundaries over
    # the point's seeds; its fits collect 16.6-18.6 dB (10th-90th percentile), and an echo
    # fitted at 15 dB or more is followed to the boundaries no detection brought
    # (FOLLOW_MARGIN_DB): 182 of 182 here, on one track (161 when only fits of 20.4 dB, the
    # lobe decision's threshold region, were followed).
    params = {"scene": "second-10db-weaker", "snr_db": -10.0, "srr_db": "off"}
    out = scene_trial(params, np.random.SeedSequence(2626, spawn_key=(38, 0)))
    assert out["expected"] == [185, 182] and out["detected"][0] == 185
    assert out["detected"][1] >= 0.95 * 182
    assert out["n_false"] == 0 and len(out["track_ids"][1]) <= 2


#: scenes.toml's point (second-10db-weaker, -10 dB SNR, reverberation at 0 dB SRR) and its
#: seed 2: the trial two tests below read, whole and cut.
WEAKER_BESIDE_STILL = {"scene": "second-10db-weaker", "snr_db": -10.0, "srr_db": 0.0}
WEAKER_BESIDE_STILL_SEED = (2626, (39, 2))


@functools.cache
def _weaker_beside_still() -> dict[str, Any]:
    """:data:`WEAKER_BESIDE_STILL`'s trial fed whole, run once per process (1.2 CPU s): both
    tests that read it only read it."""
    seed, spawn_key = WEAKER_BESIDE_STILL_SEED
    out: dict[str, Any] = scene_trial(
        WEAKER_BESIDE_STILL, np.random.SeedSequence(seed, spawn_key=spawn_key)
    )
    return out


@pytest.mark.slow
def test_a_weaker_target_followed_beside_still_reverberation_keeps_its_track() -> None:
    # scenes.toml's point (second-10db-weaker, -10 dB SNR, reverberation at 0 dB SRR), seed
    # 2: the detector misses a third of the weaker target's boundaries. Followed from its
    # fits, the echo was lost for runs of 7-23 hops where the lobe decisions moved a fit a
    # lobe off its echo's (refused) or its latest fit dipped under 15 dB: 105 of 182 before
    # (3 false, 6 tracks), 168 (1 false, 2 tracks; -1, the estimates before a track is
    # confirmed, aside) with a weak followed fit on its echo's lobe and the echo held
    # (EchoFit.held).
    out = _weaker_beside_still()
    assert out["expected"] == [185, 182] and out["detected"][0] == 185
    assert out["detected"][1] >= 0.9 * 182
    assert out["n_false"] <= 2 and len(set(out["track_ids"][1]) - {-1}) <= 2


@pytest.mark.slow
def test_gcas_keeps_the_weaker_target_on_its_lobe_beside_still_reverberation() -> None:
    # second-10db-weaker at 0 dB SNR with reverberation at 0 dB SRR, the seed of scenes.toml's
    # point where the weaker target's fits sat a grating lobe off for runs of hops: before the
    # lobe decision on the input without its still water, 150 of 182 boundaries and 28 false
    # estimates (0.15 per hop); with it 176 and 1 (hil.estimation.still_lobe).
    params = {"scene": "second-10db-weaker", "snr_db": 0.0, "srr_db": 0.0}
    out = scene_trial(params, np.random.SeedSequence(2626, spawn_key=(37, 2)))
    assert out["expected"] == [185, 182] and out["detected"][0] == 185
    assert out["detected"][1] >= 0.95 * 182
    assert out["n_false"] <= 0.02 * out["n_hops"]


def test_the_documented_still_water_sweep_is_valid() -> None:
    # docs/results.md, "Scenes": the gcas against gcas-still sweep, as written there.
    import tomllib

    from hil.evaluation.sweep_file import sweep_from_dict

    text = RESULTS_DOC.read_text(encoding="utf-8")
    block = re.search(r'```toml\n(\[sweep\]\nname = "still-scenes".*?)```', text, re.S)
    assert block is not None
    spec = sweep_from_dict(tomllib.loads(block.group(1)))
    points = spec.points()
    assert len(points) == 48 and {p["receiver"] for p in points} == {"gcas", "gcas-still"}
    for p in points:
        validate_scene_params(p)


def test_the_documented_empty_water_sweep_is_valid() -> None:
    # docs/results.md, "Scenes": the band-off scene through gcas and gcas-bg, as written there.
    import tomllib

    from hil.evaluation.sweep_file import sweep_from_dict

    text = RESULTS_DOC.read_text(encoding="utf-8")
    block = re.search(r'```toml\n(\[sweep\]\nname = "empty-water-scenes".*?)```', text, re.S)
    assert block is not None
    points = sweep_from_dict(tomllib.loads(block.group(1))).points()
    assert len(points) == 8 and {p["receiver"] for p in points} == {"gcas", "gcas-bg"}
    for p in points:
        validate_scene_params(p)


@pytest.mark.slow
def test_the_weaker_target_followed_beside_still_reverberation_is_the_same_however_cut(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # The seeded scene above (held echoes, followed fits kept on their echo's lobe beside the
    # still water) fed in 997-sample blocks and at random cuts: every estimate the same.
    import itertools

    import hil.evaluation.trials_scene as trials_scene

    # The whole run is the one the test above reads (made here first if this test runs
    # alone or first), before the receiver is wrapped.
    whole = _weaker_beside_still()
    build = trials_scene._receiver
    cuts: list[int] = []
    pieces: list[int] = []

    class Chunked:
        def __init__(self, rx: Any) -> None:
            self._rx = rx

        def process(self, x: np.ndarray) -> list[Any]:
            edges = [0, *[c for c in cuts if 0 < c < x.shape[0]], x.shape[0]]
            out: list[Any] = []
            for a, b in itertools.pairwise(edges):
                out += self._rx.process(x[a:b])
            pieces.append(len(edges) - 1)
            return out

        def __getattr__(self, name: str) -> Any:
            return getattr(self._rx, name)

    def chunked(p: dict[str, Any]) -> Any:
        rx, *rest = build(p)
        return (Chunked(rx), *rest)

    monkeypatch.setattr(trials_scene, "_receiver", chunked)
    seed, spawn_key = WEAKER_BESIDE_STILL_SEED
    rng = np.random.default_rng(17)
    for edges in (list(range(997, 200_000, 997)), sorted(rng.integers(1, 200_000, 40).tolist())):
        cuts[:] = edges
        got = scene_trial(WEAKER_BESIDE_STILL, np.random.SeedSequence(seed, spawn_key=spawn_key))
        for key in ("expected", "detected", "n_false", "range_errors_m", "speed_errors_mps"):
            assert got[key] == whole[key], key
    assert pieces == [201, 41]
    assert whole["detected"][1] >= 0.9 * 182
