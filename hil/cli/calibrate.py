"""``hil calibrate``: run a calibration, print it, store it as the current one.

Examples::

    hil calibrate latency                      # simulated loopback, stored in ./calibration
    hil calibrate response --band 4000 16000
    hil calibrate level --reference-channel 1 --reference-sensitivity -211 --reference-gain 26
    hil calibrate sound-speed --temperature 18.3
    hil calibrate sound-speed --method tof --positions=-0.4:-0.05:8
    hil calibrate stage --device "Scarlett" --stage /dev/ttyUSB0 --temperature 18.3

Without ``--device`` (or with ``--device sim://audio``) every kind runs in a simulated world
with injected truths, printed first so the user sees what the calibration should find.
A :class:`~hil.errors.ConfigError` exits with status 2 (via :mod:`hil.cli.main`); a
measurement that cannot be trusted (open loop, no echo) prints one line and exits with 1.
"""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from hil.errors import ConfigError
from hil.paths import resolve_calibration_dir

# The calibrations (and through them the audio devices and scipy.signal, about 2 s of CPU)
# are imported where a calibration runs, so that building the parser for --help stays cheap.
if TYPE_CHECKING:
    from hil.experiments.calibration.device import PlayRecordDevice
    from hil.experiments.calibration.level import ReferenceHydrophone, ReferenceSource
    from hil.experiments.calibration.positions import PositioningStage
    from hil.experiments.calibration.ranging import EchoRanger
    from hil.experiments.calibration.simworld import SimTruth
    from hil.experiments.calibration.store import CalibrationStore

EXIT_MEASUREMENT_FAILED = 1
#: The thermometer's uncertainty when --temperature-uncertainty is not given, °C.
TEMPERATURE_UNCERTAINTY_C = 0.1
SIM_DEVICE = "sim://audio"
SIMULATED_SUBDIR = "simulated"
_WHERE = (
    " Without --device it runs on a simulated bench whose truths are printed first and "
    "stores the result apart, in STORE/simulated/, where a real run never looks."
)
"""Sub-folder of the store holding the results measured on the simulated bench."""

# Internal field names -> the options that set them (hil.cli.main names them in errors).
OPTION_NAMES = {
    "repeats": "--repeats",
    "max_latency_frames": "--max-latency",
    "band_hz": "--band",
    "duration_s": "--duration",
    "amplitude": "--amplitude",
    "equaliser_taps": "--taps",
    "frequency_hz": "--frequency",
    "adc_full_scale_v": "--adc-full-scale",
    "input_gain_db": "--input-gain",
    "regularisation_db": "--regularisation",
    "output_channel": "--output-channel",
    "input_channel": "--input-channel",
    "latency_samples": "--latency",
    "distance_m": "--distance",
    "temperature_c": "--temperature",
    "salinity_ppt": "--salinity",
    "temperature_uncertainty_c": "--temperature-uncertainty",
    "positions_m": "--positions",
    "overtravel_m": "--overtravel",
    "speed_mps": "--speed",
    "sound_speed_mps": "--sound-speed",
    "gate_s": "--gate-ms",
    "averages": "--pings",
}


def parse_positions(text: str) -> list[float]:
    """``"a:b:n"`` (n evenly spaced from a to b) or ``"x1,x2,..."``, metres.

    >>> [round(x, 6) for x in parse_positions("-0.4:-0.1:4")]
    [-0.4, -0.3, -0.2, -0.1]
    >>> parse_positions("-0.3,-0.2")
    [-0.3, -0.2]
    """
    try:
        if ":" in text:
            a, b, n = text.split(":")
            return [float(v) for v in np.linspace(float(a), float(b), int(n))]
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise ConfigError(
            "--positions", text, "START:STOP:COUNT or a comma-separated list of metres",
            "e.g. --positions -0.4:-0.05:8",
        ) from exc  # fmt: skip


def _common(p: argparse.ArgumentParser, audio: bool = True) -> None:
    p.add_argument(
        "--store", type=Path, default=None,
        help="calibration store directory (default $HIL_CALIBRATION_DIR, else ./calibration); "
        "simulated results go to its simulated/ subfolder, never applied to a real run",
    )  # fmt: skip
    if audio:
        p.add_argument(
            "--device", default=None,
            help=f"audio interface name, index or audio:// URL, or {SIM_DEVICE} (default: a "
            "simulated world)",
        )  # fmt: skip
        p.add_argument("--samplerate", type=float, default=None,
                       help="Hz (default: the device's; simulated bench 48000)")  # fmt: skip
        p.add_argument("--blocksize", type=int, default=256, help="frames (default 256)")
        p.add_argument("--output-channel", type=int, default=0, help="output channel (0-based)")
        p.add_argument("--input-channel", type=int, default=0, help="input channel (0-based)")
        p.add_argument("--max-latency", type=int, default=None, help="samples (default 0.1 s)")


#: The time-of-flight options' values when left out (the ``argparse`` defaults are None, so a
#: calibration that ranges no echo can tell a given option from a left-out one and refuse it).
TANK_DEFAULTS: dict[str, Any] = {
    "positions": "-0.4:-0.05:8",
    "speed": 0.05,
    "gate_ms": (1.0, 3.0),
    "pings": 4,
}


def _stage_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--stage", default=None,
        help="stage URL, e.g. serial:///dev/ttyUSB0 (needed with --device; without it, on the"
        " simulated bench, only sim://stage)",
    )  # fmt: skip
    p.add_argument(
        "--positions", type=parse_positions, default=None,
        help="stage positions, --positions=START:STOP:COUNT or =x1,x2,... m (default "
        f"{TANK_DEFAULTS['positions']})",
    )  # fmt: skip
    p.add_argument("--speed", type=float, default=None,
                   help=f"move speed, m/s (default {TANK_DEFAULTS['speed']:g})")  # fmt: skip
    p.add_argument(
        "--gate-ms", type=float, nargs=2, default=None, metavar=("EARLIEST", "LATEST"),
        help="two-way time-of-flight gate of the target echo, ms (default 1 3)",
    )  # fmt: skip
    p.add_argument(
        "--pings", type=int, default=None,
        help=f"pings averaged per position (default {TANK_DEFAULTS['pings']})",
    )  # fmt: skip
    p.add_argument(
        "--latency", type=int, default=None,
        help="loop latency to subtract, samples (default: the stored latency calibration)",
    )  # fmt: skip


def register(sub: Any) -> None:
    """Add the ``calibrate`` sub-command and its kinds."""
    parser: argparse.ArgumentParser = sub.add_parser(
        "calibrate",
        help="calibrate latency, response, level, sound speed or the stage",
        description="Run one calibration (in simulation when no device is given), print it "
        "and store it as the current calibration of its kind (hil docs calibration). "
        "'hil calibrate KIND --help' describes each kind.",
    )
    kinds = parser.add_subparsers(dest="kind", metavar="KIND")
    kinds.required = True

    p = kinds.add_parser(
        "latency", help="loopback latency, sample-exact, repeated",
        description="Play a reference LFM chirp out of --output-channel, record it on "
        "--input-channel (a cable or the DAC monitor), find its delay with a matched filter, "
        "--repeats times: the loop latency in samples at the run's rate. Refused when the "
        "chirp does not come back (peak-to-sidelobe < 20 dB or loop gain < 1e-3)." + _WHERE,
    )  # fmt: skip
    _common(p)
    p.add_argument("--repeats", type=int, default=5, help="number of chirps (default 5)")
    p.set_defaults(func=run, kind_func=_latency)

    p = kinds.add_parser(
        "response", help="frequency response (sweep) and equaliser",
        description="Exponential sine sweep (Farina) through the transducer pair: magnitude "
        "(dB re FS/FS) and phase over --band LOW HIGH (Hz, default 5-40 % of the sample "
        "rate), and a regularised inverse FIR equaliser of --taps taps." + _WHERE,
    )  # fmt: skip
    _common(p)
    p.add_argument("--band", type=float, nargs=2, metavar=("LOW", "HIGH"), help="Hz")
    p.add_argument("--duration", type=float, default=1.0, help="sweep length, s (default 1)")
    p.add_argument("--amplitude", type=float, default=0.5, help="sweep amplitude, FS")
    p.add_argument("--taps", type=int, default=1024, help="equaliser length")
    p.add_argument("--regularisation", type=float, default=-40.0, help="dB re peak |H|^2")
    p.set_defaults(func=run, kind_func=_response)

    p = kinds.add_parser(
        "level", help="gain (FS/FS) and hydrophone sensitivity",
        description="Play a --frequency tone, fit its amplitude on the input: the loop gain "
        "(FS/FS, dB), volts with --adc-full-scale, and the hydrophone sensitivity (dB re "
        "1 V/µPa) from a reference hydrophone (--reference-channel, --reference-sensitivity) "
        "or a known source level (--source-level at --distance)." + _WHERE,
    )  # fmt: skip
    _common(p)
    p.add_argument("--frequency", type=float, default=1000.0, help="tone, Hz")
    p.add_argument("--amplitude", type=float, default=0.25, help="tone amplitude, FS")
    p.add_argument("--adc-full-scale", type=float, default=None, help="V at ADC full scale")
    p.add_argument("--input-gain", type=float, default=None, help="measured input's gain, dB")
    p.add_argument("--reference-channel", type=int, help="input of a reference hydrophone")
    p.add_argument("--reference-sensitivity", type=float, help="its dB re 1 V/µPa")
    p.add_argument("--reference-gain", type=float, default=0.0, help="its input gain, dB")
    p.add_argument("--source-level", type=float, help="dB re 1 µPa @ 1 m at full scale")
    p.add_argument("--distance", type=float, help="projector to hydrophone, m")
    p.set_defaults(func=run, kind_func=_level)

    p = kinds.add_parser(
        "sound-speed", help="c from temperature or time of flight",
        description="The water's sound speed c (m/s): from --temperature (°C; Marczak for "
        "fresh water, Mackenzie with --salinity, a real measurement kept with the real "
        "calibrations) or by time of flight of an echo at stage --positions (m)." + _WHERE,
    )  # fmt: skip
    _common(p, audio=False)
    p.add_argument("--device", default=None, help=f"audio device or {SIM_DEVICE} (tof)")
    p.add_argument("--method", choices=("temperature", "tof"), default=None,
                   help="default: temperature if --temperature is given, else tof")  # fmt: skip
    p.add_argument("--temperature", type=float, help="water temperature, °C")
    p.add_argument("--salinity", type=float, help="ppt (Mackenzie); omit for fresh water")
    p.add_argument(
        "--temperature-uncertainty", type=float, default=None,
        help=f"°C, with --method temperature (default {TEMPERATURE_UNCERTAINTY_C:g})",
    )  # fmt: skip
    _stage_options(p)
    p.set_defaults(func=run, kind_func=_sound_speed)

    p = kinds.add_parser(
        "stage", help="stage scale and backlash by echo ranging",
        description="Range an echo at stage --positions (m), approached from both sides: "
        "the stage scale (true/commanded) and its backlash (m), against a sound speed from "
        "--sound-speed, --temperature or the store." + _WHERE,
    )  # fmt: skip
    _common(p, audio=False)
    p.add_argument("--device", default=None, help=f"audio device or {SIM_DEVICE}")
    p.add_argument("--sound-speed", type=float, help="c, m/s (default: --temperature or store)")
    p.add_argument("--temperature", type=float, help="water temperature, °C")
    p.add_argument("--overtravel", type=float, default=0.005, help="m (default 0.005)")
    _stage_options(p)
    p.set_defaults(func=run, kind_func=_stage)


def _tank_options(args: argparse.Namespace) -> None:
    """Fill the time-of-flight options left out with `TANK_DEFAULTS` (in place)."""
    for name, default in TANK_DEFAULTS.items():
        if getattr(args, name) is None:
            value = parse_positions(default) if name == "positions" else default
            setattr(args, name, value)


def _truth(args: argparse.Namespace) -> SimTruth:
    """The simulated bench's truths, at ``--samplerate`` and ``--blocksize`` when given."""
    from hil.experiments.calibration.simworld import SimTruth

    rate = getattr(args, "samplerate", None)
    if rate is None:
        return SimTruth()
    if not (np.isfinite(rate) and 8000.0 <= rate <= 384000.0):
        raise ConfigError("--samplerate", rate, "8000 ... 384000 Hz")
    return SimTruth(samplerate=float(rate), blocksize=int(args.blocksize))


def _runs_simulated(args: argparse.Namespace) -> bool:
    """Whether this calibration measures the simulated bench (stored apart, never applied to
    a real run): every kind without ``--device``, except sound speed from a thermometer."""
    if args.kind == "sound-speed":
        method = args.method or ("temperature" if args.temperature is not None else "tof")
        if method == "temperature":
            return False
    return _simulated(args)


def _simulated(args: argparse.Namespace) -> bool:
    from hil.devices.table import is_simulated

    return args.device is None or is_simulated(args.device)


def _audio_device(args: argparse.Namespace, channels_in: int = 1) -> PlayRecordDevice:
    """The real audio interface named by ``--device`` (the device table opens it)."""
    from hil.devices.table import open_audio_interface
    from hil.experiments.calibration.device import from_duplex

    duplex = open_audio_interface(
        args.device, samplerate=args.samplerate or 48000.0, channels_in=channels_in,
        blocksize=args.blocksize,
    )  # fmt: skip
    return from_duplex(duplex, name=str(args.device))


def _channel_kwargs(args: argparse.Namespace) -> dict[str, Any]:
    kw = {"output_channel": args.output_channel, "input_channel": args.input_channel}
    if args.max_latency is not None:
        kw["max_latency_frames"] = args.max_latency
    return kw


def _latency(args: argparse.Namespace, truth: SimTruth) -> tuple[Any, dict[str, Any], list[str]]:
    from hil.experiments.calibration.latency import calibrate_latency
    from hil.experiments.calibration.simworld import sim_loopback

    device, lines = sim_loopback(truth) if _simulated(args) else (_audio_device(args), [])
    result = calibrate_latency(device, repeats=args.repeats, **_channel_kwargs(args))
    return result, {"device": device.name, "repeats": args.repeats}, lines


def _response(args: argparse.Namespace, truth: SimTruth) -> tuple[Any, dict[str, Any], list[str]]:
    from hil.experiments.calibration.response import calibrate_response
    from hil.experiments.calibration.simworld import sim_transducer

    device, lines = sim_transducer(truth) if _simulated(args) else (_audio_device(args), [])
    band = None if args.band is None else (args.band[0], args.band[1])
    result = calibrate_response(
        device, band_hz=band, duration_s=args.duration, amplitude=args.amplitude,
        equaliser_taps=args.taps, regularisation_db=args.regularisation,
        **_channel_kwargs(args),
    )  # fmt: skip
    settings = {"device": device.name, "band_hz": band, "duration_s": args.duration}
    return result, settings, lines


def _level(args: argparse.Namespace, truth: SimTruth) -> tuple[Any, dict[str, Any], list[str]]:
    from hil.experiments.calibration.level import (
        ReferenceHydrophone,
        ReferenceSource,
        calibrate_level,
    )
    from hil.experiments.calibration.simworld import sim_hydrophones

    reference: ReferenceHydrophone | ReferenceSource | None = None
    if args.reference_sensitivity is not None or args.reference_channel is not None:
        if args.reference_sensitivity is None or args.reference_channel is None:
            raise ConfigError(
                "--reference-channel/--reference-sensitivity", None, "both given together",
                "name the reference hydrophone's input and its sensitivity (dB re 1 V/µPa)",
            )  # fmt: skip
        reference = ReferenceHydrophone(
            args.reference_channel, args.reference_sensitivity, args.reference_gain
        )
    if args.source_level is not None or args.distance is not None:
        if reference is not None or args.source_level is None or args.distance is None:
            raise ConfigError(
                "--source-level/--distance", None,
                "both given together, and not with a reference hydrophone",
                "use one reference: a hydrophone or a source of known level",
            )  # fmt: skip
        reference = ReferenceSource(args.source_level, args.distance)
    sim = _simulated(args)
    channels_in = 2 if isinstance(reference, ReferenceHydrophone) else 1
    device, lines = sim_hydrophones(truth) if sim else (_audio_device(args, channels_in), [])
    full_scale = (
        args.adc_full_scale
        if args.adc_full_scale is not None
        else (truth.adc_full_scale_v if sim else 1.0)
    )
    gain = args.input_gain if args.input_gain is not None else (truth.input_gain_db if sim else 0)
    result = calibrate_level(
        device, frequency_hz=args.frequency, amplitude=args.amplitude,
        adc_full_scale_v=full_scale, input_gain_db=gain, reference=reference,
        **_channel_kwargs(args),
    )  # fmt: skip
    settings = {"device": device.name, "frequency_hz": args.frequency, "amplitude": args.amplitude}
    return result, settings, lines


@contextlib.contextmanager
def _tank(
    args: argparse.Namespace, truth: SimTruth, store: CalibrationStore
) -> Iterator[tuple[PositioningStage, EchoRanger, list[str], int]]:
    """Stage and echo ranger: simulated, or the real audio device and GRBL stage."""
    from hil.devices.table import check_device_url, is_simulated
    from hil.experiments.calibration.ranging import EchoRanger
    from hil.experiments.calibration.simworld import sim_tank

    gate = (args.gate_ms[0] * 1e-3, args.gate_ms[1] * 1e-3)
    stage_url = None if args.stage is None else check_device_url(args.stage, "stage", "--stage")
    if _simulated(args):
        if stage_url is not None and not is_simulated(stage_url):
            # The simulated bench tows its own simulated stage: a real one would sit unused.
            raise ConfigError(
                "--stage", args.stage, "sim://stage or left out on the simulated bench",
                "give --device (the audio interface) to calibrate with a real stage",
            )  # fmt: skip
        with sim_tank(truth) as (stage, tank, lines):
            latency = truth.tank_latency_samples if args.latency is None else args.latency
            ranger = EchoRanger(tank.device(), gate, latency_samples=latency, averages=args.pings)
            yield stage, ranger, lines, latency
        return
    if stage_url is None:
        raise ConfigError("--stage", args.stage, "a GRBL serial URL when --device is given")
    from hil.devices.table import open_stage

    latency = args.latency
    if latency is None:
        record = store.current("latency")
        latency = 0 if record is None else record.result.latency_samples
    device = _audio_device(args)
    with open_stage(stage_url, field="--stage") as grbl:
        # As hil tank-run does: out of any alarm (reset, then $H or $X) before moving.
        grbl.make_ready(lambda step: print(f"stage: {step}", flush=True))
        yield (
            grbl,
            EchoRanger(device, gate, latency_samples=latency, averages=args.pings),
            [],
            latency,
        )


def _sound_speed(
    args: argparse.Namespace, truth: SimTruth, store: CalibrationStore
) -> tuple[Any, dict[str, Any], list[str]]:
    from hil.experiments.calibration.sound_speed import (
        calibrate_sound_speed_temperature,
        calibrate_sound_speed_tof,
    )

    method = args.method or ("temperature" if args.temperature is not None else "tof")
    if method == "temperature":
        if args.temperature is None:
            raise ConfigError("--temperature", None, "a water temperature in °C")
        for option, value in (("--device", args.device), ("--stage", args.stage),
                              ("--latency", args.latency), ("--positions", args.positions),
                              ("--speed", args.speed), ("--gate-ms", args.gate_ms),
                              ("--pings", args.pings)):  # fmt: skip
            if value is not None:
                # c from the thermometer: no echo is ranged, so no device would be used.
                raise ConfigError(
                    option, value, "left out with --method temperature (nothing is measured)",
                    "drop it, or use --method tof to measure c by time of flight",
                )  # fmt: skip
        uncertainty = args.temperature_uncertainty
        if uncertainty is None:
            uncertainty = TEMPERATURE_UNCERTAINTY_C
        result = calibrate_sound_speed_temperature(
            args.temperature, salinity_ppt=args.salinity, temperature_uncertainty_c=uncertainty
        )
        settings = {"method": method, "temperature_c": args.temperature, "salinity": args.salinity}
        return result, settings, []
    if args.temperature_uncertainty is not None:
        # Time of flight takes c's uncertainty from the fit of its slope; the temperature
        # only gives a cross-check c, reported without an uncertainty.
        raise ConfigError(
            "--temperature-uncertainty", args.temperature_uncertainty,
            "left out with --method tof, whose c takes its uncertainty from the fit of the "
            "echo's time of flight (the temperature only cross-checks c)",
            "drop it, or use --method temperature --temperature °C",
        )  # fmt: skip
    _tank_options(args)
    temperature = args.temperature
    if temperature is None and _simulated(args):
        temperature = truth.temperature_c  # the simulated tank's thermometer log
    with _tank(args, truth, store) as (stage, ranger, lines, latency):
        result = calibrate_sound_speed_tof(
            stage, ranger, args.positions, speed_mps=args.speed,
            temperature_c=temperature, salinity_ppt=args.salinity,
        )  # fmt: skip
    settings = {"method": method, "positions_m": args.positions, "latency_samples": latency}
    return result, settings, lines


def _stage(
    args: argparse.Namespace, truth: SimTruth, store: CalibrationStore
) -> tuple[Any, dict[str, Any], list[str]]:
    from hil.experiments.calibration.sound_speed import calibrate_sound_speed_temperature
    from hil.experiments.calibration.stage import calibrate_stage

    _tank_options(args)
    c = args.sound_speed
    source = "--sound-speed"
    if c is None and args.temperature is not None:
        c = calibrate_sound_speed_temperature(args.temperature).sound_speed_mps
        source = f"--temperature {args.temperature:g} °C"
    if c is None:
        # A time-of-flight c already absorbed the stage scale (it measures c / scale): only a
        # temperature-based c is independent of the stage.
        record = store.current("sound-speed")
        if record is not None and record.result.method == "temperature":
            c, source = record.result.sound_speed_mps, f"stored {record.id}"
    if c is None and _simulated(args):
        c, source = truth.sound_speed_mps, f"simulated thermometer {truth.temperature_c:g} °C"
    if c is None:
        raise ConfigError(
            "--sound-speed", None, "a sound speed (or --temperature, or a stored calibration)",
            f"run: hil calibrate sound-speed --store {store.root}",
        )  # fmt: skip
    with _tank(args, truth, store) as (stage, ranger, lines, latency):
        settings = {"positions_m": args.positions, "latency_samples": latency}
        result = calibrate_stage(
            stage, ranger, args.positions, sound_speed_mps=c,
            overtravel_m=args.overtravel, speed_mps=args.speed,
        )  # fmt: skip
    settings["sound_speed_from"] = source
    return result, settings, [*lines, f"sound speed used: {c:.3f} m/s ({source})"]


def run(args: argparse.Namespace) -> int:
    """Run the chosen calibration, print it and store it."""
    from hil.experiments.calibration.device import CalibrationError
    from hil.experiments.calibration.store import CalibrationStore

    if getattr(args, "device", None) is not None:
        from hil.devices.table import audio_interface_url

        # One spelling: a bare name reads as audio://NAME, audio://sim as sim://audio.
        args.device = audio_interface_url(args.device, "--device")
    blocksize = getattr(args, "blocksize", None)
    if blocksize is not None and blocksize < 1:
        raise ConfigError("--blocksize", blocksize, "an integer >= 1 frames", "e.g. 256")
    truth = _truth(args)
    root = resolve_calibration_dir(args.store)
    kind: str = args.kind
    simulated = _runs_simulated(args)
    store = CalibrationStore(root / SIMULATED_SUBDIR if simulated else root)
    from hil.outputs import writable_folder

    writable_folder(store.root, "--store (or HIL_CALIBRATION_DIR)")
    try:
        if kind in ("sound-speed", "stage"):
            result, settings, lines = args.kind_func(args, truth, store)
        else:
            result, settings, lines = args.kind_func(args, truth)
    except CalibrationError as exc:
        print(f"hil calibrate {kind}: measurement refused: {exc}", flush=True)
        return EXIT_MEASUREMENT_FAILED
    settings = {**settings, "simulated": simulated}
    if simulated:
        settings["truth"] = dict(truth.__dict__)
        for line in lines:
            print(f"[truth] {line}")
    for line in result.summary():
        print(line)
    record = store.save(kind, result, settings)
    print(f"stored: {record.path} (id {record.id}, now current for {kind!r})")
    if simulated:
        print(f"simulated: kept apart in {store.root}; a real run never applies it")
    return 0
