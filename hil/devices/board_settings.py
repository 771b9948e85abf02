"""Declarative, typed settings of the transducer board, checked before anything is sent.

Each setting is a :class:`Setting` descriptor, in the settings style every device shares
(:class:`~hil.devices.setting_descriptor.TypedSetting`): a type, a unit and a validator.
Assigning an invalid value raises :class:`~hil.errors.ConfigError` naming the setting, the
value, the allowed range and the unit. :meth:`BoardSettings.check_against` then checks the
values against what the board said it can do (CAPABILITIES) before the driver sends
CONFIGURE.

>>> s = BoardSettings(sample_rate_hz=1_000_000, adc_channels=2)
>>> s.adc_gain_db = 130.0
Traceback (most recent call last):
...
hil.errors.ConfigError: adc_gain_db = 130.0 is not allowed: must be -120.0 .. 120.0 dB; \
the protocol carries gains in 0.01 dB within +-120 dB
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, TypeVar, overload

import numpy as np
import numpy.typing as npt

from firmware_protocol import Capabilities, Configure, SampleFormat
from hil.devices.setting_descriptor import Check, TypedSetting
from hil.errors import ConfigError

T = TypeVar("T")


class Setting(TypedSetting[T]):
    """One typed setting with a unit and a validator (:class:`TypedSetting`), its value
    stored on the instance (``default`` until assigned)."""

    def __init__(
        self,
        convert: Callable[[Any], T],
        *,
        unit: str,
        check: Check,
        allowed: str,
        default: T,
        hint: str = "",
    ) -> None:
        super().__init__(convert, unit=unit, check=check, allowed=allowed, hint=hint)
        self.default = default

    @overload
    def __get__(self, obj: None, objtype: type | None = None) -> Setting[T]: ...

    @overload
    def __get__(self, obj: object, objtype: type | None = None) -> T: ...

    def __get__(self, obj: object | None, objtype: type | None = None) -> Setting[T] | T:
        if obj is None:
            return self
        value: T = obj.__dict__.get(self.name, self.default)
        return value

    def __set__(self, obj: object, value: Any) -> None:
        obj.__dict__[self.name] = self.validate(value)


def _int(value: Any) -> int:
    if isinstance(value, float) and not value.is_integer():
        raise ValueError(value)
    if isinstance(value, str):
        raise TypeError(value)
    return int(value)


def _format(value: Any) -> SampleFormat:
    if isinstance(value, str):
        return SampleFormat[value.upper()]  # KeyError is not ValueError: map it
    return SampleFormat(value)


def _format_safe(value: Any) -> SampleFormat:
    try:
        return _format(value)
    except KeyError:
        raise ValueError(value) from None


def _between(low: float, high: float) -> Check:
    return lambda v: math.isfinite(v) and low <= v <= high


_FORMATS = ", ".join(f.name.lower() for f in SampleFormat)
_GAIN_HINT = "the protocol carries gains in 0.01 dB within +-120 dB"


class BoardSettings:
    """What the host asks the board for: rate, channels, formats and gains.

    Channels ``n`` means channels ``0 .. n-1`` (channel mask ``2**n - 1``).
    """

    sample_rate_hz = Setting(
        _int, unit="Hz", check=_between(1, 100_000_000), allowed="1 .. 100000000",
        default=1_000_000, hint="the tank-board preset runs at 1000000 Hz",
    )  # fmt: skip
    dac_channels = Setting(
        _int, unit="channels", check=_between(1, 16), allowed="1 .. 16", default=2
    )
    adc_channels = Setting(
        _int, unit="channels", check=_between(1, 16), allowed="1 .. 16", default=2
    )
    dac_format = Setting(
        _format_safe, unit="", check=lambda v: True, allowed=f"one of {_FORMATS}",
        default=SampleFormat.INT16,
    )  # fmt: skip
    adc_format = Setting(
        _format_safe, unit="", check=lambda v: True, allowed=f"one of {_FORMATS}",
        default=SampleFormat.INT16,
    )  # fmt: skip
    dac_gain_db = Setting(
        float, unit="dB", check=_between(-120.0, 120.0), allowed="-120.0 .. 120.0",
        default=0.0, hint=_GAIN_HINT,
    )  # fmt: skip
    adc_gain_db = Setting(
        float, unit="dB", check=_between(-120.0, 120.0), allowed="-120.0 .. 120.0",
        default=0.0, hint=_GAIN_HINT,
    )  # fmt: skip

    NAMES = (
        "sample_rate_hz",
        "dac_channels",
        "adc_channels",
        "dac_format",
        "adc_format",
        "dac_gain_db",
        "adc_gain_db",
    )

    def __init__(self, **values: Any) -> None:
        for name, value in values.items():
            if name not in self.NAMES:
                raise ConfigError("board setting", name, f"one of {', '.join(self.NAMES)}")
            setattr(self, name, value)

    def __repr__(self) -> str:
        inner = ", ".join(f"{n}={getattr(self, n)!r}" for n in self.NAMES)
        return f"BoardSettings({inner})"

    def check_against(self, caps: Capabilities) -> None:
        """Raise ConfigError if the board cannot do these settings (before CONFIGURE)."""
        if self.sample_rate_hz not in caps.sample_rates_hz:
            rates = ", ".join(str(r) for r in caps.sample_rates_hz)
            raise ConfigError(
                "sample_rate_hz", self.sample_rate_hz, f"one of {rates} Hz", "the board's rates"
            )
        for side, most in (("dac", caps.dac_channels), ("adc", caps.adc_channels)):
            name = f"{side}_channels"
            if getattr(self, name) > most:
                raise ConfigError(name, getattr(self, name), f"1 .. {most} channels", "the board")
        formats = caps.sample_formats
        for name in ("dac_format", "adc_format"):
            if getattr(self, name) not in formats:
                allowed = ", ".join(f.name.lower() for f in formats)
                raise ConfigError(name, getattr(self, name).name.lower(), f"one of {allowed}")
        low, high = caps.gain_min_cdb / 100.0, caps.gain_max_cdb / 100.0
        for name in ("dac_gain_db", "adc_gain_db"):
            if not low <= getattr(self, name) <= high:
                raise ConfigError(name, getattr(self, name), f"{low} .. {high} dB", "the board")

    def to_configure(self) -> Configure:
        """The CONFIGURE message for these settings."""
        return Configure(
            sample_rate_hz=self.sample_rate_hz,
            dac_channel_mask=(1 << self.dac_channels) - 1,
            adc_channel_mask=(1 << self.adc_channels) - 1,
            dac_format=self.dac_format,
            adc_format=self.adc_format,
            dac_gain_cdb=round(self.dac_gain_db * 100),
            adc_gain_cdb=round(self.adc_gain_db * 100),
        )


_FULL_SCALE = {SampleFormat.INT16: 32768.0, SampleFormat.INT24: 8388608.0}
_DTYPES = {SampleFormat.INT16: np.int16, SampleFormat.INT24: np.int32}


def to_wire_samples(block: npt.ArrayLike, fmt: SampleFormat, channels: int) -> npt.NDArray[Any]:
    """A DAC block as wire samples of ``fmt``, shape (n, channels).

    Floats are full-scale (+-1.0), rounded and clipped for the integer formats; integer
    arrays pass unchanged (counts). A 1-D block is played on every channel.

    >>> to_wire_samples(np.array([0.5, -1.0, 2.0]), SampleFormat.INT16, 2).tolist()
    [[16384, 16384], [-32768, -32768], [32767, 32767]]
    """
    array = np.asarray(block)
    if array.ndim == 1:
        array = np.repeat(array[:, None], channels, axis=1)
    if array.ndim != 2 or array.shape[1] != channels:
        raise ConfigError(
            "DAC block shape", array.shape, f"(n,) or (n, {channels})", "one column per channel"
        )
    if fmt is SampleFormat.FLOAT32:
        return array.astype(np.float32)
    if np.issubdtype(array.dtype, np.integer):
        return array.astype(_DTYPES[fmt])
    scale = _FULL_SCALE[fmt]
    counts = np.rint(array * scale)
    np.clip(counts, -scale, scale - 1, out=counts)
    return counts.astype(_DTYPES[fmt])
