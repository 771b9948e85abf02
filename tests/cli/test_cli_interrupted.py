"""A command stopped by Ctrl-C or a stop signal exits with 130 and says so, also where the
interruption was raised inside a compiled kernel (it comes out of that call as a
``SystemError`` caused by it)."""

from __future__ import annotations

import argparse

import pytest

from hil.cli import estimate
from hil.cli.main import EXIT_INTERRUPTED, main
from hil.interrupts import RunInterrupted


def _sighup_inside_a_kernel(args: argparse.Namespace) -> int:
    raise SystemError("returned a result with an exception set") from RunInterrupted("SIGHUP")


def _a_real_system_error(args: argparse.Namespace) -> int:
    raise SystemError("a kernel's own failure")


def test_an_interruption_inside_a_kernel_exits_as_interrupted(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setattr(estimate, "run", _sighup_inside_a_kernel)
    assert main(["estimate", "--schedule", "s.json", "--input", "x.wav"]) == EXIT_INTERRUPTED
    assert capsys.readouterr().err.strip() == "hil estimate: interrupted (SIGHUP)"


def test_any_other_system_error_is_not_taken_for_an_interruption(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(estimate, "run", _a_real_system_error)
    with pytest.raises(SystemError, match="a kernel's own failure"):
        main(["estimate", "--schedule", "s.json", "--input", "x.wav"])
