"""The C reference firmware cross-compiled for a Cortex-M4, run in QEMU's MPS2 AN386.

:func:`build_image` runs ``make cross`` in ``firmware_protocol/c`` (``arm-none-eabi-gcc``,
Debian ``gcc-arm-none-eabi`` + ``libnewlib-arm-none-eabi``). :class:`QemuBoard` boots the
image in ``qemu-system-arm -M mps2-an386`` with its UART0 on a host pty (:attr:`port_name`),
which the host driver opens like the serial port of a real board. The emulated MCU has no
DAC or ADC: the firmware's analog path is a loopback cable in software (SPEC-conforming
otherwise; see ``firmware_protocol/c/mcu/mps2_an386.c``).
"""

from __future__ import annotations

import re
import shutil
import subprocess
from types import TracebackType

from sim_devices.board.c_firmware import (
    BUILD_DIR,
    FIRMWARE_DIR,
    CFirmwareUnavailable,
    stop_process,
)

IMAGE = BUILD_DIR / "arm" / "casfw-mps2-an386.elf"
"""The Cortex-M4 image."""
MACHINE = "mps2-an386"


def tools_missing() -> str | None:
    """Why the Cortex-M4 image cannot be built and run here, or None if it can."""
    for tool, package in (
        ("make", "make"),
        ("arm-none-eabi-gcc", "gcc-arm-none-eabi libnewlib-arm-none-eabi"),
        ("qemu-system-arm", "qemu-system-arm"),
    ):
        if shutil.which(tool) is None:
            return f"'{tool}' is not installed (Debian: apt-get install {package})"
    return None


def build_image() -> str:
    """``make cross`` (incremental); returns its size report. Raises CFirmwareUnavailable."""
    missing = tools_missing()
    if missing:
        raise CFirmwareUnavailable(missing)
    result = subprocess.run(
        ["make", "-s", "-C", str(FIRMWARE_DIR), "cross"],
        capture_output=True,
        text=True,
        check=False,
    )
    if result.returncode != 0:
        raise CFirmwareUnavailable(
            f"make cross failed:\n{(result.stderr or result.stdout)[-2000:]}"
        )
    return result.stdout


class QemuBoard:
    """The firmware image booted in QEMU; :attr:`port_name` is its UART0 as a host pty."""

    def __init__(self) -> None:
        build_image()
        self.process = subprocess.Popen(
            [
                "qemu-system-arm",
                "-M",
                MACHINE,
                "-display",
                "none",
                "-monitor",
                "none",
                "-serial",
                "pty",
                "-kernel",
                str(IMAGE),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        assert self.process.stdout is not None
        line = self.process.stdout.readline()
        found = re.search(r"(/dev/pts/\d+)", line)
        if found is None:
            self.close()
            raise CFirmwareUnavailable(f"QEMU did not report its UART pty: {line.strip()!r}")
        self.port_name = found.group(1)

    def close(self) -> None:
        """Stop QEMU (idempotent)."""
        stop_process(self.process)

    def __enter__(self) -> QemuBoard:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
