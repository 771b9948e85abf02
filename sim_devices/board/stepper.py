"""The simulated board as a device under test stepped on board time (golden conversations).

``step(t_ns, host)`` runs one service pass (``tick``) at board time ``t_ns``, then delivers
the host bytes, and returns every byte the board sent: the contract of
:class:`firmware_protocol.conversations.Device`, which the C reference firmware's stepper
(:mod:`sim_devices.board.c_firmware`) offers too.

This board is the reference of the golden conversations: ``python -m
sim_devices.board.stepper --write`` records ``firmware_protocol/golden_conversations.json``
(``--check`` exits 1 if the file differs from what the board says now).
"""

from __future__ import annotations

import sys
from typing import Any

from firmware_protocol import SampleFormat, conversations
from firmware_protocol.conversations import BOARD
from sim_devices.board.core import SimulatedBoard
from sim_devices.board.spec import BoardSpec
from sim_devices.board.worlds import LoopbackWorld


def conversation_spec(board: dict[str, Any] = BOARD) -> BoardSpec:
    """The :class:`BoardSpec` of the golden conversations' board description."""
    return BoardSpec(
        dac_channels=board["dac_channels"],
        adc_channels=board["adc_channels"],
        formats=tuple(SampleFormat[name] for name in board["formats"]),
        sample_rates_hz=tuple(board["sample_rates_hz"]),
        dac_buffer_samples=board["dac_buffer_samples"],
        adc_buffer_samples=board["adc_buffer_samples"],
        max_frame_len=board["max_frame_len"],
        gain_min_cdb=board["gain_min_cdb"],
        gain_max_cdb=board["gain_max_cdb"],
        firmware=tuple(board["firmware"]),
        board_serial=board["board_serial"],
        sync_interval_s=board["sync_interval_ns"] / 1e9,
        status_interval_s=board["status_interval_ns"] / 1e9,
        temperature_c=board["temperature_cdeg"] / 100,
    )


class PythonBoardStepper:
    """A fresh :class:`SimulatedBoard` (powered up at board time 0) driven step by step."""

    name = "python"

    def __init__(self, spec: BoardSpec | None = None) -> None:
        self._t = 0.0
        self.board = SimulatedBoard(
            spec or conversation_spec(), clock=lambda: self._t, world=LoopbackWorld()
        )

    @property
    def adc_clipped_samples(self) -> int:
        """ADC values clipped at conversion since power-up."""
        return self.board.adc_clipped_samples

    def step(self, t_ns: int, host: bytes) -> bytes:
        """Service at ``t_ns`` (ns, not before the last step), then receive ``host``."""
        self._t = t_ns / 1e9
        self.board.tick()
        if host:
            self.board.receive_data(host)
        return self.board.data_to_send()


if __name__ == "__main__":
    sys.exit(conversations.main(PythonBoardStepper))
