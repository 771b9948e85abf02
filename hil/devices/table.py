"""One table of the devices named by URL (python-can's ``BACKENDS``): for each kind of
URL, the roles it can fill (``daq``: the run's DAC/ADC, a board or an audio interface;
``stage``: the GRBL stage), whether it is simulated, how it is checked without opening
anything, and how it opens. Every command that opens a device by URL (``hil tank-run``,
``hil stage``, ``hil calibrate``, the bluesky devices) goes through :func:`check_device_url`,
:func:`open_stage`, :func:`open_real_daq` or :func:`open_audio_interface`; the built-in
simulated tank opens its board with :func:`open_board` over the link it made.

=========================================  ===========  =========  =============================
URL                                        roles        simulated  checked / opened by
=========================================  ===========  =========  =============================
``/dev/ttyACM0``, ``serial://``,           daq, stage   no         the transport registry
``loop://``, ``socket://``, ``rfc2217://``,                         (:mod:`hil.transports`);
``hwgrep://``, ``usb://``, ``spy://``                               the board or GRBL driver
``sim://board[?impl=c]``                   daq          yes        the built-in simulated tank
``sim://stage``                            stage        yes        the GRBL driver over the
                                                                    simulated controller
``sim://audio``                            daq          yes        the built-in simulated tank
                                                                    (the simulated interface)
``audio://DEVICE``                         daq          no         :mod:`hil.devices.audio.daq`
=========================================  ===========  =========  =============================

Every simulated device is spelled ``sim://DEVICE``; ``audio://sim`` is read as
``sim://audio`` (with a deprecation warning).

>>> check_device_url("audio://sim?rate=192000", "daq")
'sim://audio?rate=192000'
>>> entry_for("sim://stage?via=memory").simulated, entry_for("/dev/ttyUSB0").simulated
(True, False)
>>> check_device_url("sim://audio", "stage", "devices.stage")
Traceback (most recent call last):
...
hil.errors.ConfigError: devices.stage = 'sim://audio' is not allowed: must be a stage URL \
(a serial port or transport URL, or sim://stage); sim://audio is a DAC/ADC
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

from hil.errors import ConfigError

if TYPE_CHECKING:
    from hil.acquisition.device import StreamingDevice
    from hil.devices.audio.contract import DuplexBackend
    from hil.devices.clock import Clock, VirtualClock
    from hil.devices.grbl import ByteLink, GrblStage
    from hil.transports.base import Transport

ROLES = ("daq", "stage")
_ROLE_WORDS = {
    "daq": "a DAC/ADC URL (a board's port or transport URL, audio://DEVICE, sim://board or "
    "sim://audio)",
    "stage": "a stage URL (a serial port or transport URL, or sim://stage)",
}
_WHAT = {"daq": "a DAC/ADC", "stage": "a stage"}

#: Seconds of capture a run's DAC/ADC ring holds.
RING_S = 8.0
#: The board's watchdog (ms of its clock): it stops when the host has sent nothing for this
#: long (a crashed or stalled host), so a run never leaves it streaming unattended.
WATCHDOG_MS = 1000
#: The simulated board's in the real-time simulated tank: the tank is a child process on the
#: same CPUs, scaled in time, so a stall of the machine (seconds on a loaded CI host) must not
#: stop it.
SIM_WATCHDOG_MS = 10_000

DaqOpener = Callable[[str, float, "Clock", int], "StreamingDevice"]
"""``open(url, fs_hz, clock, keepalive_ms)``: a real DAC/ADC, opened (not configured)."""
StageOpener = Callable[..., "GrblStage"]
"""``open(target, **options)``: a GRBL stage driver (not yet open); ``options`` are
:class:`~hil.devices.grbl.GrblStage`'s keywords."""


@dataclass(frozen=True)
class DeviceEntry:
    """One row of the table (see the module docstring)."""

    name: str
    roles: tuple[str, ...]
    simulated: bool
    #: ``check(url, field, role) -> canonical url``: raises ConfigError naming ``field``.
    check: Callable[[str, str, str], str]
    #: How a real DAC/ADC of this kind opens (None: not a real DAC/ADC).
    open_daq: DaqOpener | None = None
    #: How a stage of this kind opens (None: not a stage).
    open_stage: StageOpener | None = None


def _check_transport(url: str, field: str, role: str) -> str:
    from hil.transports.registry import check_url

    check_url(url, field, "board" if role == "daq" else "stage")
    return url


def _check_audio(url: str, field: str, role: str) -> str:
    from hil.devices.audio.daq import canonical_audio_url, parse_audio_url

    canonical = canonical_audio_url(url)
    parse_audio_url(canonical)
    return canonical


def open_board(
    target: str | Transport,
    fs: float,
    clock: Clock,
    keepalive_ms: int,
    virtual_time: VirtualClock | None = None,
) -> StreamingDevice:
    """The transducer board at ``target`` (a URL or an open link) opened for a run at ``fs``
    Hz: 1 DAC channel, 2 ADC channels, :data:`RING_S` of ring; on ``virtual_time`` when
    given (an in-process simulated board)."""
    from hil.devices.board import Board
    from hil.devices.board_settings import BoardSettings

    settings = BoardSettings(sample_rate_hz=int(fs), dac_channels=1, adc_channels=2)
    board = Board(
        target,
        settings=settings,
        clock=None if virtual_time is not None else clock,
        virtual_time=virtual_time,
        ring_seconds=RING_S,
        keepalive_ms=keepalive_ms,
    )
    return board.open()


def _open_board(url: str, fs: float, clock: Clock, keepalive_ms: int) -> StreamingDevice:
    return open_board(url, fs, clock, keepalive_ms)


def _open_audio(url: str, fs: float, clock: Clock, keepalive_ms: int) -> StreamingDevice:
    from hil.devices.audio.daq import AudioDaq

    return AudioDaq.from_url(url, sample_rate_hz=int(fs), ring_seconds=RING_S).open()


def _open_grbl(target: str | ByteLink, **options: Any) -> GrblStage:
    from hil.devices.grbl import GrblStage

    return GrblStage(target, **options)


TRANSPORT = DeviceEntry("transport", ROLES, False, _check_transport, _open_board, _open_grbl)
SIM_BOARD = DeviceEntry("sim://board", ("daq",), True, _check_transport)
SIM_STAGE = DeviceEntry("sim://stage", ("stage",), True, _check_transport, None, _open_grbl)
SIM_AUDIO = DeviceEntry("sim://audio", ("daq",), True, _check_audio)
AUDIO = DeviceEntry("audio://", ("daq",), False, _check_audio, _open_audio)

#: ``sim://DEVICE`` entries by device name.
SIMULATED = {"board": SIM_BOARD, "stage": SIM_STAGE, "audio": SIM_AUDIO}
#: A ``sim://`` name the table does not know: the transport registry refuses it, with a hint.
SIM_UNKNOWN = DeviceEntry("sim://?", ROLES, True, _check_transport)


def entry_for(url: str) -> DeviceEntry:
    """The table row ``url`` falls in (a transport for any URL the others do not claim: the
    transport registry then checks it)."""
    from hil.devices.audio.daq import DEPRECATED_SIM_AUDIO_URL

    scheme, _, rest = url.partition("://") if "://" in url else ("", "", url)
    if scheme == "sim":
        device = rest.split("?", 1)[0].split("/", 1)[0]
        return SIMULATED.get(device, SIM_UNKNOWN)
    if scheme == "audio":
        bare = url.split("?", 1)[0]
        return SIM_AUDIO if bare == DEPRECATED_SIM_AUDIO_URL else AUDIO
    return TRANSPORT


def check_device_url(url: str, role: str, field: str | None = None) -> str:
    """``url`` checked for ``role`` (``daq`` or ``stage``) without opening anything, as the
    setting ``field`` (default ``devices.board`` / ``devices.stage``); its canonical
    spelling."""
    if role not in ROLES:
        raise ConfigError("role", role, f"one of {', '.join(ROLES)}")
    field = field or ("devices.board" if role == "daq" else "devices.stage")
    if not isinstance(url, str) or not url:
        raise ConfigError(field, url, "a non-empty transport URL or device path")
    entry = entry_for(url)
    if role not in entry.roles:
        other = next(r for r in entry.roles if r != role)
        raise ConfigError(
            field, url, _ROLE_WORDS[role], f"{url.split('?', 1)[0]} is {_WHAT[other]}"
        )
    return entry.check(url, field, role)


def is_simulated(url: str) -> bool:
    """True for a simulated device's URL (``sim://...``, or ``audio://sim``)."""
    return entry_for(url).simulated


def open_real_daq(url: str, fs: float, clock: Clock, keepalive_ms: int) -> StreamingDevice:
    """The real DAC/ADC at ``url`` opened (not configured) for a run at ``fs`` Hz, on the
    driver ``clock``; ``keepalive_ms`` is the board's watchdog (an audio interface has
    none). Simulated devices open with the built-in simulated tank instead."""
    entry = entry_for(url)
    if entry.open_daq is None:
        raise ConfigError(
            "devices.board", url, "a real DAC/ADC", "simulated devices run in the built-in tank"
        )
    return entry.open_daq(url, fs, clock, keepalive_ms)


def open_stage(
    target: str | ByteLink, *, field: str = "devices.stage", **options: Any
) -> GrblStage:
    """The GRBL stage driver for ``target`` (a stage URL, checked as the setting ``field``,
    or an open link), not yet open: ``with open_stage(url) as stage:`` or ``.open()``.
    ``options`` are :class:`~hil.devices.grbl.GrblStage`'s keywords (``clock=``,
    ``soft_limits=``, ``transport_options=``, ...)."""
    if not isinstance(target, str):
        return _open_grbl(target, **options)
    url = check_device_url(target, "stage", field)
    opener = entry_for(url).open_stage
    if opener is None:  # every row with the stage role has an opener
        raise ConfigError(field, url, _ROLE_WORDS["stage"])
    return opener(url, **options)


def audio_interface_url(device: str, field: str = "--device") -> str:
    """The canonical URL of the audio interface ``device`` names: an ``audio://`` or
    ``sim://audio`` URL, or a bare interface name or index (``Scarlett``, ``2``), read as
    ``audio://NAME``.

    >>> audio_interface_url("Scarlett 2i2"), audio_interface_url("audio://sim")
    ('audio://Scarlett%202i2', 'sim://audio')
    """
    if not isinstance(device, str) or not device.strip():
        raise ConfigError(field, device, "an audio interface name, index or audio:// URL")
    url = device if "://" in device else "audio://" + quote(device.strip(), safe="")
    if entry_for(url) not in (AUDIO, SIM_AUDIO):
        raise ConfigError(
            field, device, "an audio interface name, index, audio://DEVICE or sim://audio"
        )
    return check_device_url(url, "daq", field)


def open_audio_interface(
    device: str,
    *,
    samplerate: float,
    channels_in: int,
    blocksize: int,
    field: str = "--device",
) -> DuplexBackend:
    """The real audio interface ``device`` names (see :func:`audio_interface_url`) as a
    full-duplex stream of 1 output and ``channels_in`` input channels at ``samplerate`` Hz,
    ``blocksize`` frames per callback; not yet open. The simulated interface is refused:
    it runs in a simulated world (the calibration bench or the built-in tank)."""
    from hil.devices.audio.daq import parse_audio_url
    from hil.devices.audio.portaudio_backend import SoundDeviceDuplex

    url = audio_interface_url(device, field)
    if is_simulated(url):
        raise ConfigError(field, device, "a real audio interface", "sim://audio is simulated")
    settings = parse_audio_url(url).settings(samplerate, channels_in, 1, blocksize)
    return SoundDeviceDuplex(settings)
