"""The instrument snapshot of a run: what each open device says it is, for the recording's
NeXus entry (:mod:`hil.recording.instrument`).

- ``board`` (NXdetector): the VERSION reply (firmware version, board serial, protocol and
  schema hash) and CAPABILITIES (max frame, buffers, channels, rates);
- ``audio`` (NXdetector) instead, for an audio interface: device, host API, the driver's
  latency, rate and block size;
- ``stage`` (NXpositioner): GRBL's ``$I`` (``[VER:...]``, ``[OPT:...]``) and every ``$$``
  setting by number, as the controller printed it;
- ``host`` (NXcollection): host name, platform, Python;

each with the URL the experiment gave and what it resolved to (port, USB ids).
"""

from __future__ import annotations

import platform
from typing import Any

from hil.transports.identity import port_identity


def board_snapshot(board: Any, url: str) -> dict[str, Any]:
    """The transducer board (a :class:`~hil.devices.board.Board`, opened)."""
    out: dict[str, Any] = {"nx_class": "NXdetector", "url": url, "link": str(board.url)}
    out.update(port_identity(board.transport))
    version, caps = board.version, board.capabilities
    if version is not None:
        out["firmware_version"] = (
            f"{version.firmware_major}.{version.firmware_minor}.{version.firmware_patch}"
        )
        out["board_serial"] = int(version.board_serial)
        out["protocol_version"] = f"{version.protocol_major}.{version.protocol_minor}"
        out["schema_hash"] = f"0x{version.schema_hash:08x}"
    if caps is not None:
        out["max_frame_len"] = int(caps.max_frame_len)
        out["dac_buffer_samples"] = int(caps.dac_buffer_samples)
        out["adc_buffer_samples"] = int(caps.adc_buffer_samples)
        out["dac_channels"] = int(caps.dac_channels)
        out["adc_channels"] = int(caps.adc_channels)
        out["sample_rates_hz"] = [int(r) for r in caps.sample_rates_hz]
    return out


def audio_snapshot(daq: Any, url: str) -> dict[str, Any]:
    """An audio interface (a :class:`~hil.devices.audio.daq.AudioDaq`, opened)."""
    backend = daq.backend
    settings = backend.settings
    out: dict[str, Any] = {
        "nx_class": "NXdetector",
        "url": url,
        "sample_rate_hz": int(settings.samplerate),
        "blocksize": int(settings.blocksize),
        "latency_setting": str(settings.latency),
    }
    out.update(backend.describe())
    return out


def stage_snapshot(stage: Any, url: str) -> dict[str, Any]:
    """The GRBL stage (a :class:`~hil.devices.grbl.GrblStage`, opened): asks ``$I``."""
    info = stage.build_info()
    out: dict[str, Any] = {"nx_class": "NXpositioner", "name": "x", "url": url}
    link = getattr(stage.transport, "url", None)
    if link is not None:
        out["link"] = str(link)
    out.update(port_identity(stage.transport))
    for key, prefix in (("build_info", "[VER:"), ("build_options", "[OPT:")):
        line = next((m for m in info if m.startswith(prefix)), None)
        if line is not None:
            out[key] = line
    settings = stage.connection.settings
    out["settings"] = {str(n): str(settings[n]) for n in sorted(settings)}
    return out


def host_snapshot() -> dict[str, Any]:
    """The computer the run ran on."""
    return {
        "hostname": platform.node(),
        "platform": platform.platform(),
        "python": platform.python_version(),
    }


def instrument_snapshot(
    board: Any, board_url: str, stage: Any, stage_url: str
) -> dict[str, dict[str, Any]]:
    """The snapshot of a run's devices (the board or audio interface, the stage, the host)."""
    from hil.devices.audio.daq import AudioDaq

    daq = (
        ("audio", audio_snapshot(board, board_url))
        if isinstance(board, AudioDaq)
        else ("board", board_snapshot(board, board_url))
    )
    return {
        daq[0]: daq[1],
        "stage": stage_snapshot(stage, stage_url),
        "host": host_snapshot(),
    }
