"""Bad values that used to end in a traceback are refused in one line naming the option or
the file (exit status 2)."""

from __future__ import annotations

from pathlib import Path

import pytest

from .conftest import empty_recording, one_line_error


def test_a_symlink_loop_as_the_experiment_file(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    loop = tmp_path / "loop.toml"
    loop.symlink_to(loop)
    assert one_line_error(capsys, ["tank-run", str(loop)]) == (
        f"hil tank-run: error: Too many levels of symbolic links: {loop}"
    )


def test_a_negative_waveform_seed(capsys: pytest.CaptureFixture[str]) -> None:
    assert one_line_error(capsys, ["waveform", "--duration", "0.05", "--seed", "-1"]) == (
        "hil waveform: error: --seed = -1 is not allowed: must be an integer >= 0; e.g. --seed 1"
    )


@pytest.mark.parametrize(
    ("option", "allowed"),
    [
        ("m_hops=abc", "an integer for m_hops (it is 10 now); write --option m_hops=10"),
        ("m_hops=1.5", "an integer for m_hops (it is 10 now); write --option m_hops=10"),
        ("max_speed_mps=fast", "a number for max_speed_mps (it is 30.0 now); write --option"
         " max_speed_mps=30.0"),
    ],
)  # fmt: skip
def test_a_replay_option_of_the_wrong_kind(
    option: str, allowed: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = empty_recording(tmp_path / "run.h5")
    assert one_line_error(capsys, ["replay", str(run), "--option", option]) == (
        f"hil replay: error: --option = '{option}' is not allowed: must be {allowed}"
    )


@pytest.mark.parametrize(
    ("host", "why"),
    [
        ("no.such.host.invalid", None),  # does not resolve (the resolver's words vary)
        ("192.0.2.1", "Cannot assign requested address"),  # TEST-NET-1: not this machine's
    ],
)
def test_watch_blames_an_unusable_host_not_the_port(
    host: str, why: str | None, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    run = empty_recording(tmp_path / "run.h5")
    err = one_line_error(capsys, ["watch", str(run), "--host", host])
    assert err.startswith(
        f"hil watch: error: --host (host) = '{host}' is not allowed: must be a name or address"
        " of this machine; cannot listen there: "
    )
    assert err.endswith("; use 127.0.0.1 (this machine only) or 0.0.0.0 (every interface)")
    if why is not None:
        assert why in err
