"""Coded values carried in message fields: sample formats, NAK codes, alarm bits, log levels."""

from __future__ import annotations

from enum import IntEnum, IntFlag


class SampleFormat(IntEnum):
    """Sample encoding of DAC/ADC data; every format is little-endian and interleaved."""

    INT16 = 1
    """2 bytes, two's complement, full scale -32768 .. 32767."""
    INT24 = 2
    """3 bytes, two's complement, sign-extended on unpacking to int32; -8388608 .. 8388607."""
    FLOAT32 = 3
    """4 bytes, IEEE 754 binary32; full scale -1.0 .. 1.0."""

    @property
    def size(self) -> int:
        """Bytes per sample (one channel, one instant)."""
        return _SIZES[self]

    @property
    def mask_bit(self) -> int:
        """Bit of this format in CAPABILITIES.formats: ``1 << (code - 1)``."""
        return 1 << (self.value - 1)


_SIZES = {SampleFormat.INT16: 2, SampleFormat.INT24: 3, SampleFormat.FLOAT32: 4}


class NakCode(IntEnum):
    """Why the device refused a host message (NAK.code)."""

    UNKNOWN_MESSAGE = 1
    """The message type is unknown to this firmware (and the frame was not flagged optional)."""
    BAD_PAYLOAD = 2
    """The payload is too short or a field value is out of range."""
    BAD_STATE = 3
    """The message is not allowed in the device's current state."""
    UNSUPPORTED_RATE = 4
    UNSUPPORTED_CHANNELS = 5
    UNSUPPORTED_FORMAT = 6
    GAIN_OUT_OF_RANGE = 7
    CREDIT_EXCEEDED = 8
    """DAC data beyond the granted credit; the excess samples were dropped."""
    START_INDEX_PASSED = 9
    """START named a sample index the board clock has already passed."""
    BUSY = 10
    INTERNAL = 255


class Alarm(IntFlag):
    """STATUS.alarms bits; the device sets a bit while the condition holds."""

    NONE = 0

    OVER_TEMPERATURE = 0x0001
    WATCHDOG_EXPIRED = 0x0002
    """No host frame within the keepalive timeout: DAC output stopped, state is STOPPED."""
    DAC_UNDERRUN = 0x0004
    ADC_OVERRUN = 0x0008
    ADC_CLIPPING = 0x0010
    SUPPLY_FAULT = 0x0020


class LogLevel(IntEnum):
    """LOG.level."""

    DEBUG = 0
    INFO = 1
    WARNING = 2
    ERROR = 3


class Role(IntEnum):
    """Which end of the link a :class:`~firmware_protocol.connection.Connection` plays."""

    HOST = 1
    """The PC: sends HELLO, CONFIGURE, START, STOP, KEEPALIVE, DAC data."""
    DEVICE = 2
    """The board: sends VERSION, CAPABILITIES, ACK/NAK, credits, ADC data, STATUS, SYNC, LOG."""
