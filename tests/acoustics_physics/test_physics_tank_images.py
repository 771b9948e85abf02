"""The tank's image sources, own echoes and late tail against pyroomacoustics' image-source
method (``ShoeBox``) and the Sabine/Eyring formulas."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from scipy.special import j1

from hil.errors import ConfigError
from sim_devices.acoustics.beam import OmniBeam, PistonBeam
from sim_devices.acoustics.delay import TwoWayPath
from sim_devices.acoustics.directivity import TableBeam, Transducer
from sim_devices.acoustics.images import box_images, check_order, image_count
from sim_devices.acoustics.tank import Tank, echo_path_count, echo_paths
from sim_devices.acoustics.tank_response import (
    TankEchoes,
    TankEchoSettings,
    specular_paths,
    t60_s,
    tank_impulse_response,
)
from sim_devices.acoustics.trajectory import Fixed

pra = pytest.importorskip("pyroomacoustics")

C = 1482.0
SIZE = (12.0, 4.0, 2.5)
# pyroomacoustics takes energy absorption per wall; its reflection amplitude is sqrt(1 - a).
# It holds image positions and damping in float32: 2e-6 m over 30 m, 1e-7 relative.
POS_TOL_M = 4e-6
WALL, BOTTOM, TOP = 0.8, 0.7, 0.95


def _room(order: int, source: tuple[float, float, float], mic: tuple[float, float, float]) -> Any:
    """A ShoeBox of the tank in pyroomacoustics' frame (z up from the bottom)."""
    r = {"west": WALL, "east": WALL, "south": WALL, "north": WALL, "floor": BOTTOM,
         "ceiling": TOP}  # fmt: skip
    mats = {k: pra.Material(1.0 - v * v) for k, v in r.items()}
    room = pra.ShoeBox(list(SIZE), fs=192000, materials=mats, max_order=order,
                       air_absorption=False)  # fmt: skip
    room.add_source([source[0], source[1], source[2] + SIZE[2]])
    room.add_microphone([mic[0], mic[1], mic[2] + SIZE[2]])
    room.image_source_model()
    return room


def _sorted(points: np.ndarray) -> np.ndarray:
    """Column order that sorts points (3, K) lexicographically (rounded to 0.1 mm: images
    are centimetres apart at least, and pyroomacoustics holds them in float32)."""
    return np.lexsort(np.round(points, 4))


@pytest.mark.parametrize("order", [0, 1, 2, 3, 4])
@pytest.mark.parametrize("source", [(0.5, 2.0, -1.2), (3.3, 0.7, -2.1)])
def test_images_match_pyroomacoustics(order: int, source: tuple[float, float, float]) -> None:
    tank = Tank(*SIZE, wall_reflection=WALL, bottom_reflection=BOTTOM, surface_reflection=TOP)
    ours = box_images(tank, order)
    room = _room(order, source, (6.0, 2.0, -1.0))
    theirs = room.sources[0]
    pos = ours.positions(source).T.copy()
    pos[2] += SIZE[2]
    a, b = _sorted(theirs.images), _sorted(pos)
    assert len(ours) == theirs.images.shape[1] == image_count(order)
    assert np.max(np.abs(theirs.images[:, a] - pos[:, b])) < POS_TOL_M
    assert np.array_equal(theirs.orders[a], ours.order[b])
    # pyroomacoustics keeps the damping in float32
    assert np.max(np.abs(theirs.damping[0, a] - ours.gain[b])) < 1e-6


def test_own_echo_delays_and_amplitudes_match_pyroomacoustics() -> None:
    tank = Tank(*SIZE, wall_reflection=WALL, bottom_reflection=BOTTOM, surface_reflection=TOP)
    src, mic = (0.5, 2.0, -1.2), (0.6, 2.1, -1.1)
    paths = specular_paths(tank, src, mic, 3, C)
    room = _room(3, src, mic)
    s = room.sources[0]
    d = np.sqrt(np.sum((s.images - room.mic_array.R[:, :1]) ** 2, axis=0))
    keep = s.orders >= 1
    order = np.argsort(d[keep], kind="stable")
    assert np.allclose(paths.delay_s, d[keep][order] / C, rtol=0, atol=POS_TOL_M / C)
    assert np.allclose(paths.amplitude, s.damping[0, keep][order] / d[keep][order], rtol=1e-6)
    assert np.array_equal(paths.order, s.orders[keep][order])


def test_surface_flips_the_sign_once_per_bounce() -> None:
    tank = Tank(*SIZE, wall_reflection=WALL, bottom_reflection=BOTTOM)
    im = box_images(tank, 3)
    magnitude = WALL ** im.counts[:, :4].sum(axis=1) * BOTTOM ** im.counts[:, 4]
    assert np.allclose(im.gain, magnitude * (-1.0) ** im.counts[:, 5], rtol=1e-14, atol=0)
    assert np.array_equal(np.sign(im.gain), (-1.0) ** im.counts[:, 5])
    assert im.label(int(np.flatnonzero(im.counts[:, 5] == 2)[0])).endswith("surface×2")


@pytest.mark.parametrize("order", [1, 2, 3])
def test_echo_paths_are_the_image_pairs_up_to_the_order_per_round_trip(order: int) -> None:
    tank = Tank(*SIZE, wall_reflection=WALL, bottom_reflection=BOTTOM, surface_reflection=TOP)
    sonar, target = (0.5, 2.0, -1.2), (6.0, 2.3, -0.9)
    paths = list(echo_paths(Fixed(sonar), Fixed(target), tank, order))
    assert len(paths) == echo_path_count(order) == (13, 85, 377)[order - 1]
    assert paths[0].name == "direct"
    # Every (out image i, back image j) with order(i) + order(j) <= N, each once: the images
    # are pyroomacoustics' (sonar as the source), the gain R_i R_j, and the solved two-way
    # delay the two image distances over c.
    room = _room(order, sonar, target)
    img = room.sources[0].images.T.astype(np.float64)
    img[:, 2] -= SIZE[2]
    img_gain = room.sources[0].damping[0].astype(np.float64)
    img_order = room.sources[0].orders
    pairs = set()
    for p in paths:
        out = p.tx.position(np.zeros(1))[0]
        back = p.rx.position(np.zeros(1))[0]
        i = int(np.argmin(np.linalg.norm(img - out, axis=1)))
        j = int(np.argmin(np.linalg.norm(img - back, axis=1)))
        assert (
            np.linalg.norm(img[i] - out) < POS_TOL_M and np.linalg.norm(img[j] - back) < POS_TOL_M
        )
        assert p.orders == (img_order[i], img_order[j]) and sum(p.orders) <= order
        assert p.gain == pytest.approx(img_gain[i] * img_gain[j], rel=1e-6)
        r_out, r_back = (np.linalg.norm(np.asarray(target) - x) for x in (out, back))
        sol = TwoWayPath(p.tx, p.target, p.rx, C).solve(np.array([1.0]))
        assert sol.delay_s[0] == pytest.approx((r_out + r_back) / C, abs=1e-11)
        pairs.add((i, j))
    expected = {
        (i, j)
        for i in range(len(img))
        for j in range(len(img))
        if img_order[i] + img_order[j] <= order
    }
    assert pairs == expected


def test_surface_out_and_back_is_second_order_with_a_positive_sign() -> None:
    tank = Tank(*SIZE, wall_reflection=WALL, bottom_reflection=BOTTOM)
    paths = {p.name: p for p in echo_paths(Fixed((0.5, 2, -1)), Fixed((8, 2, -1)), tank, 2)}
    assert "out surface / back surface" not in {
        p.name for p in echo_paths(Fixed((0.5, 2, -1)), Fixed((8, 2, -1)), tank, 1)
    }
    assert paths["out surface / back surface"].gain == 1.0
    assert paths["out surface / back bottom"].gain == pytest.approx(-BOTTOM)
    assert paths["out direct / back bottom+surface"].gain == pytest.approx(-BOTTOM)


def test_sabine_matches_pyroomacoustics_and_eyring_with_uniform_absorption() -> None:
    tank = Tank(*SIZE, wall_reflection=0.9, bottom_reflection=0.8, surface_reflection=-1.0)
    r = {"west": 0.9, "east": 0.9, "south": 0.9, "north": 0.9, "floor": 0.8, "ceiling": 1.0}
    room = pra.ShoeBox(list(SIZE), fs=48000, max_order=1,
                       materials={k: pra.Material(1.0 - v * v) for k, v in r.items()})  # fmt: skip
    room.c = C
    with np.errstate(divide="ignore"):  # the surface's zero absorption, wall by wall
        expected = room.rt60_theory("sabine")
    assert t60_s(tank, C, "sabine") == pytest.approx(expected, rel=1e-6)
    uniform = Tank(*SIZE, 0.85, 0.85, 0.85)
    room_u = pra.ShoeBox(list(SIZE), fs=48000, max_order=1, materials=pra.Material(1 - 0.85**2))
    room_u.c = C
    assert t60_s(uniform, C, "eyring") == pytest.approx(room_u.rt60_theory("eyring"), rel=1e-6)
    # the formulas themselves: V = 120 m³, S = 176 m²
    alpha = 1 - 0.85**2
    assert t60_s(uniform, C, "sabine") == pytest.approx(
        24 * math.log(10) * 120 / (C * 176 * alpha), rel=1e-12
    )


def test_tail_decays_at_the_t60_and_carries_the_diffuse_energy() -> None:
    tank = Tank(6.0, 3.0, 2.0, wall_reflection=0.8, bottom_reflection=0.8)
    fs = 48000.0
    settings = TankEchoSettings(order=0, tail=True, t60_formula="sabine", tail_s=0.2, seed=3)
    h = tank_impulse_response(tank, (1.0, 1.5, -1.0), (1.0, 1.5, -1.0), C, fs, settings)
    t60 = t60_s(tank, C, "sabine")
    # energy in 10 ms windows: slope of 10 log10 against time is -60 dB per T60
    win = int(0.01 * fs)
    start = int(0.02 * fs)
    e = np.array([np.sum(h[k : k + win] ** 2) for k in range(start, start + 12 * win, win)])
    t = (start + win / 2 + np.arange(e.size) * win) / fs
    slope = np.polyfit(t, 10 * np.log10(e), 1)[0]
    assert -60.0 / slope == pytest.approx(t60, rel=0.05)
    # level: 4 pi c / V per second (every image missing at order 0), once the known decay
    # is taken out; 4800 samples of Gaussian noise: 2 % standard error
    n = np.arange(start, start + 10 * win)
    level = np.mean(h[n] ** 2 * 10.0 ** (6.0 * n / fs / t60)) * fs
    assert level == pytest.approx(4 * np.pi * C / 36.0, rel=0.06)


def test_tail_leaves_out_the_images_it_has() -> None:
    tank = Tank(6.0, 3.0, 2.0, wall_reflection=0.8, bottom_reflection=0.8)
    fs = 48000.0
    at = (1.0, 1.5, -1.0)
    spec = tank_impulse_response(tank, at, at, C, fs, TankEchoSettings(order=6, tail=False))
    full = tank_impulse_response(tank, at, at, C, fs, TankEchoSettings(order=6, tail=True))
    tail = full[: spec.size] - spec
    first_missing = int(np.flatnonzero(tail)[0])
    # nothing of the tail before the nearest order-7 image arrives
    nxt = box_images(tank, 7)
    r7 = np.linalg.norm(nxt.positions(at)[nxt.order == 7] - np.asarray(at), axis=1)
    assert first_missing == math.ceil(float(np.min(r7)) / C * fs)


def test_projector_directivity_per_path_direction() -> None:
    tank = Tank(*SIZE, wall_reflection=0.9, bottom_reflection=0.9)
    at = (0.5, 2.0, -1.2)
    piston = Transducer(PistonBeam(ka=4.0), (1.0, 0.0, 0.0))
    omni = specular_paths(tank, at, at, 1, C)
    beamed = specular_paths(tank, at, at, 1, C, tx=piston)
    # the far wall x=L is on the axis: unchanged; wall x=0 is behind the baffle: silent; the
    # surface, bottom and side walls are at 90°, the grazing response |2 J1(ka)/ka|
    far = np.isclose(omni.distance_m, 2 * (SIZE[0] - 0.5))
    behind = np.isclose(omni.distance_m, 1.0)
    assert np.array_equal(beamed.amplitude[far], omni.amplitude[far])
    assert np.all(beamed.amplitude[behind] == 0.0)
    side = ~(far | behind)
    grazing = abs(2 * j1(4.0) / 4.0)
    assert np.allclose(beamed.amplitude[side], omni.amplitude[side] * grazing, rtol=1e-3)


def test_transducer_responses() -> None:
    table = TableBeam([0.0, 90.0, 180.0], [0.0, -20.0, -40.0])
    t = Transducer(table, (0.0, 0.0, 2.0))
    r = t.response(np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 0.0, -3.0]]))
    assert np.allclose(r, [1.0, 0.1, 0.01], rtol=1e-3)
    assert Transducer(OmniBeam(), (1, 0, 0)).mean_intensity() == 1.0
    # piston: ka = 4, on axis 1, first null at ka sin(theta) = 3.8317
    p = Transducer(PistonBeam(ka=4.0), (1.0, 0.0, 0.0))
    theta = math.asin(3.8317 / 4.0)
    assert p.response(np.array([[math.cos(theta), math.sin(theta), 0.0]]))[0] < 1e-3
    assert 0 < p.mean_intensity() < 0.5


def test_tank_echo_stream_is_chunk_invariant() -> None:
    tank = Tank(6.0, 3.0, 2.0, wall_reflection=0.8, bottom_reflection=0.8)
    fs = 48000.0
    h = tank_impulse_response(tank, (1.0, 1.5, -1.0), (1.2, 1.5, -1.0), C, fs,
                              TankEchoSettings(order=2, tail=True, tail_s=0.05))  # fmt: skip

    def source(n0: int, count: int) -> np.ndarray:
        return np.cos(2 * np.pi * 6000.0 * np.arange(n0, n0 + count) / fs)

    one = TankEchoes(h, source).generate(40000)
    s = TankEchoes(h, source)
    parts = np.concatenate([s.generate(n) for n in (1, 999, 17000, 3, 21997)])
    assert np.array_equal(one, parts)
    # steady state from sample 0 (the transmission before it rings on): the first samples
    # equal those a whole number of tone periods (8 samples) later, past the response
    late = 8 * (h.size // 8 + 1)
    assert np.allclose(one[:200], one[late : late + 200], rtol=0, atol=1e-12 * np.max(abs(one)))


def test_bad_orders_and_settings_are_refused_with_their_field() -> None:
    for bad in (-1, 41, 1.5, True):
        with pytest.raises(ConfigError, match=r"tank\.image_order .*0 to 40"):
            check_order(bad)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match=r"tank\.t60_formula .*eyring, sabine"):
        TankEchoSettings(t60_formula="norris")
    with pytest.raises(ConfigError, match=r"beam\.angles_deg .*0 to 180"):
        TableBeam([10.0, 180.0], [0.0, -3.0])
    with pytest.raises(ConfigError, match=r"beam\.axis .*non-zero"):
        Transducer(OmniBeam(), (0.0, 0.0, 0.0))
