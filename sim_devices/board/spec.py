"""What the simulated board is: channels, formats, rates, buffers, firmware identity."""

from __future__ import annotations

from dataclasses import dataclass

from firmware_protocol import (
    MAX_FRAME_LEN,
    PROTOCOL_MAJOR,
    PROTOCOL_MINOR,
    SCHEMA_HASH,
    Capabilities,
    SampleFormat,
)
from firmware_protocol.constants import DAC_RUNS


@dataclass(frozen=True)
class BoardSpec:
    """Static properties of a simulated board.

    Attributes
    ----------
    dac_channels, adc_channels:
        Channel counts (1 .. 16).
    formats:
        Supported sample formats.
    sample_rates_hz:
        Supported sample rates, Hz (the first is the ``tank-board`` rate, 1 MS/s).
    dac_buffer_samples, adc_buffer_samples:
        FIFO sizes, sample frames.
    max_frame_len:
        Largest decoded frame the board accepts, bytes.
    gain_min_cdb, gain_max_cdb:
        Gain range of DAC and ADC, 0.01 dB.
    firmware, board_serial:
        Identity reported in VERSION.
    protocol_version, schema_hash:
        What the firmware speaks (change them to play an incompatible board).
    sync_interval_s, status_interval_s:
        Board-clock seconds between SYNC and between STATUS messages.
    temperature_c:
        Reported board temperature, degC.
    dac_runs:
        Runs of consecutive queued DAC indices the board holds (gaps + 1): a DAC_DATA that
        would start one more is refused NAK BUSY (SPEC 5.2 check 6(d)).
    """

    dac_channels: int = 2
    adc_channels: int = 2
    formats: tuple[SampleFormat, ...] = (
        SampleFormat.INT16,
        SampleFormat.INT24,
        SampleFormat.FLOAT32,
    )
    sample_rates_hz: tuple[int, ...] = (1_000_000, 500_000, 250_000, 192_000, 96_000, 48_000)
    dac_buffer_samples: int = 1 << 18  # 262 ms at 1 MS/s: rides out host scheduling hiccups
    adc_buffer_samples: int = 1 << 16
    max_frame_len: int = MAX_FRAME_LEN
    gain_min_cdb: int = -4000
    gain_max_cdb: int = 4000
    firmware: tuple[int, int, int] = (1, 0, 0)
    board_serial: int = 0x0B0A4D01
    protocol_version: tuple[int, int] = (PROTOCOL_MAJOR, PROTOCOL_MINOR)
    schema_hash: int = SCHEMA_HASH
    sync_interval_s: float = 0.1
    status_interval_s: float = 0.25
    temperature_c: float = 31.5
    dac_runs: int = DAC_RUNS

    def capabilities(self) -> Capabilities:
        """The CAPABILITIES message this board sends after VERSION."""
        return Capabilities(
            dac_channels=self.dac_channels,
            adc_channels=self.adc_channels,
            formats=sum(f.mask_bit for f in self.formats),
            dac_buffer_samples=self.dac_buffer_samples,
            adc_buffer_samples=self.adc_buffer_samples,
            max_frame_len=self.max_frame_len,
            gain_min_cdb=self.gain_min_cdb,
            gain_max_cdb=self.gain_max_cdb,
            sample_rates_hz=self.sample_rates_hz,
        )
