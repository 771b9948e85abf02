"""The one error tree (:mod:`hil.errors`): every device error is one of unavailable, refused,
timed out or lost, under ``HilError``, and names its device's URL; the old class names
still import, and the transport errors' old home still resolves."""

from __future__ import annotations

import pytest

from hil.devices.audio.daq import AudioStreamLost
from hil.devices.audio.jack_ports import JackToolError
from hil.devices.audio.portaudio_backend import AudioUnavailableError
from hil.devices.board import Board, BoardCommandError, BoardError
from hil.devices.stage_errors import (
    StageAlarmError,
    StageCommandError,
    StageError,
    StageHeldError,
    StageLimitError,
    StageTimeoutError,
)
from hil.errors import (
    ConfigError,
    DeviceError,
    DeviceLost,
    DeviceRefused,
    DeviceTimedOut,
    DeviceUnavailable,
    HilError,
    TransportClosedError,
    TransportError,
    TransportOpenError,
    TransportTimeoutError,
    device_url,
)
from hil.experiments.live.stops import DeviceLostError
from hil.transports import open_transport
from sim_devices.board.c_firmware import CFirmwareUnavailable
from sim_devices.stage import GrblSimConfig, ManualClock


@pytest.mark.parametrize(
    ("cls", "kind"),
    [
        (TransportOpenError, DeviceUnavailable),
        (AudioUnavailableError, DeviceUnavailable),
        (CFirmwareUnavailable, DeviceUnavailable),
        (JackToolError, DeviceUnavailable),
        (BoardCommandError, DeviceRefused),
        (StageCommandError, DeviceRefused),
        (StageAlarmError, DeviceRefused),
        (StageHeldError, DeviceRefused),
        (TransportTimeoutError, DeviceTimedOut),
        (StageTimeoutError, DeviceTimedOut),
        (TransportClosedError, DeviceLost),
        (DeviceLostError, DeviceLost),
        (AudioStreamLost, DeviceLost),
    ],
)
def test_each_device_error_is_one_of_four_kinds(
    cls: type[Exception], kind: type[Exception]
) -> None:
    kinds = (DeviceUnavailable, DeviceRefused, DeviceTimedOut, DeviceLost)
    assert [k for k in kinds if issubclass(cls, k)] == [kind]
    assert issubclass(cls, DeviceError) and issubclass(cls, HilError)


def test_the_old_roots_stay_under_the_tree() -> None:
    assert issubclass(StageError, DeviceError) and issubclass(BoardError, DeviceError)
    assert issubclass(TransportError, DeviceError)
    assert issubclass(ConfigError, HilError) and issubclass(ConfigError, ValueError)
    assert issubclass(StageLimitError, ConfigError)  # refused before anything is sent
    # Callers that caught the built-in bases still catch these.
    assert issubclass(DeviceLostError, RuntimeError)
    assert issubclass(AudioUnavailableError, RuntimeError)


def test_a_message_starts_with_the_url_once() -> None:
    assert str(DeviceTimedOut("no answer", url="/dev/ttyUSB0")) == "/dev/ttyUSB0: no answer"
    assert str(DeviceRefused("no answer")) == "no answer"
    already = TransportClosedError("loop://: link lost while reading (hang-up)", url="loop://")
    assert str(already) == "loop://: link lost while reading (hang-up)"
    lost = DeviceLostError("stage", "sim://stage", "EOF", "the cable")
    assert (str(lost), lost.url) == ("stage sim://stage lost: EOF; check the cable", "sim://stage")


def test_a_driver_names_an_error_only_once() -> None:
    error = DeviceLost("link closed")
    assert device_url(error, "serial:///dev/ttyACM0") is error
    device_url(error, "usb://1209:ca50")  # the first name stays
    assert str(error) == "serial:///dev/ttyACM0: link closed"


def _stage(**config: object):  # type: ignore[no-untyped-def]
    from hil.devices.table import open_stage

    return open_stage(
        "sim://stage?via=memory",
        clock=ManualClock(0.0),
        wait_step=0.5,
        transport_options={"config": GrblSimConfig(**config)},  # type: ignore[arg-type]
    )


def test_a_stage_in_alarm_refuses_a_move_naming_its_url() -> None:
    with _stage(homing=True) as stage, pytest.raises(StageAlarmError) as err:
        stage.move_to(-0.1, 0.005)
    assert str(err.value).startswith("sim://stage?via=memory: stage is in ALARM")
    assert err.value.url == "sim://stage?via=memory"


def test_a_rejected_line_names_the_stage_url() -> None:
    error = StageCommandError(20, "Unsupported command", "G5 X1", url="/dev/ttyUSB0")
    assert str(error) == (
        "/dev/ttyUSB0: GRBL rejected 'G5 X1' with error:20 (Unsupported command); nothing from"
        " that line was executed: fix the command or the controller state and send it again"
    )
    assert (error.code, error.line, error.url) == (20, "G5 X1", "/dev/ttyUSB0")


class _SilentLink:
    """A link on which nothing ever answers (the controller's power is off)."""

    url = "socket://grbl.lab:23"
    timeout = 0.0

    def write(self, data: bytes) -> int:
        return len(data)

    def read(self, size: int) -> bytes:
        return b""

    def close(self) -> None:
        pass


def test_a_silent_stage_times_out_naming_its_url() -> None:
    from hil.devices.table import open_stage

    stage = open_stage(_SilentLink(), clock=ManualClock(0.0), wait_step=0.5, open_timeout=2.0)
    with pytest.raises(StageTimeoutError) as err:
        stage.open()
    assert str(err.value).startswith("socket://grbl.lab:23: no ")
    assert "check the cable, the port and the controller's power" in str(err.value)


def test_a_board_used_before_opening_names_its_url() -> None:
    board = Board("loop://")
    with pytest.raises(BoardError) as err:
        board.configure()
    assert str(err.value) == (
        "loop://: the board is not open: call open() or use 'with Board(...)'"
    )


def test_a_missing_port_is_unavailable_naming_the_path() -> None:
    with pytest.raises(DeviceUnavailable) as err:
        open_transport("/dev/does-not-exist-28")
    assert str(err.value).startswith("cannot open '/dev/does-not-exist-28': ")


def test_the_transport_errors_old_home_still_resolves() -> None:
    import firmware_protocol
    from firmware_protocol import errors as protocol_errors

    with pytest.warns(DeprecationWarning, match="moved to hil.errors.TransportError"):
        assert protocol_errors.TransportError is TransportError
    with pytest.warns(DeprecationWarning):
        assert firmware_protocol.TransportClosedError is TransportClosedError
    with pytest.raises(AttributeError):
        _ = protocol_errors.NoSuchError  # type: ignore[attr-defined]
