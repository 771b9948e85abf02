"""Wiring JACK ports with the ``jack_lsp`` / ``jack_connect`` command-line tools (jackd2).

PortAudio's JACK host API registers one client (``PortAudio`` by default) with ports
``in_0, in_1, ...`` and ``out_0, out_1, ...`` when a stream is opened (before it starts), and
connects them to the physical ``system`` ports when it starts. Connecting ``out_k`` to
``in_k`` gives an exact digital loopback. The server is the one ``JACK_DEFAULT_SERVER`` names.
"""

from __future__ import annotations

import re
import shutil
import subprocess

from hil.errors import DeviceUnavailable

PORT_PATTERN = re.compile(r"^(?P<client>PortAudio[^:]*):(?P<kind>in|out)_(?P<index>\d+)$")


class JackToolError(DeviceUnavailable, RuntimeError):
    """A JACK command-line tool is missing or failed."""


def _run(*args: str, timeout_s: float = 10.0) -> str:
    if shutil.which(args[0]) is None:
        raise JackToolError(f"{args[0]} not found; install it (Debian: apt-get install jackd2)")
    try:
        proc = subprocess.run(args, capture_output=True, text=True, timeout=timeout_s, check=False)
    except subprocess.TimeoutExpired:
        raise JackToolError(
            f"{' '.join(args)} did not answer within {timeout_s:g} s; is the JACK server busy?"
        ) from None
    if proc.returncode != 0:
        raise JackToolError(
            f"{' '.join(args)} failed with status {proc.returncode}: "
            f"{tool_error(proc.stderr or proc.stdout)}; is the JACK server running?"
        )
    return proc.stdout


def tool_error(output: str) -> str:
    r"""The line that says what went wrong in a JACK tool's output: its last ``Error:``
    line, else its last line (libjack adds lines of internals before it).

    >>> tool_error("Cannot connect to server socket err = No such file or directory\n"
    ...            "JackShmReadWritePtr::~JackShmReadWritePtr - Init not done for -1\n"
    ...            "Error: cannot connect to JACK, server is not running.\n")
    'cannot connect to JACK, server is not running'
    >>> tool_error("")
    'no message'
    """
    lines = [line.strip() for line in output.splitlines() if line.strip()]
    errors = [line for line in lines if line.lower().startswith("error:")]
    last = (errors or lines or ["no message"])[-1]
    if last.lower().startswith("error:"):
        last = last[len("error:") :].strip()
    return last.rstrip(".")


def jack_ports() -> list[str]:
    """Names of every port of the JACK server (``jack_lsp``)."""
    return [line.strip() for line in _run("jack_lsp").splitlines() if line.strip()]


def portaudio_ports(ports: list[str]) -> tuple[list[str], list[str]]:
    """PortAudio's (output, input) ports among ``ports``, each sorted by channel index.

    Examples
    --------
    >>> portaudio_ports(["system:capture_1", "PortAudio:in_1", "PortAudio:out_0",
    ...                  "PortAudio:in_0", "PortAudio:out_1"])
    (['PortAudio:out_0', 'PortAudio:out_1'], ['PortAudio:in_0', 'PortAudio:in_1'])
    """
    found: dict[str, list[tuple[int, str]]] = {"in": [], "out": []}
    for port in ports:
        m = PORT_PATTERN.match(port)
        if m:
            found[m["kind"]].append((int(m["index"]), port))
    return [p for _, p in sorted(found["out"])], [p for _, p in sorted(found["in"])]


def connect(source: str, destination: str) -> None:
    """Connect two JACK ports (``jack_connect``)."""
    _run("jack_connect", source, destination)


def wire_portaudio_loopback(channels: int) -> list[tuple[str, str]]:
    """Connect PortAudio's ``out_k`` to ``in_k`` for ``k < channels``; return the pairs.

    Call it after the stream is opened and before it starts, so the loop exists from the
    first sample. (PortAudio also connects its ports to the ``system`` ports on start; on
    the dummy driver those carry silence, so the loopback stays exact.)
    """
    outs, ins = portaudio_ports(jack_ports())
    if len(outs) < channels or len(ins) < channels:
        raise JackToolError(
            f"PortAudio has {len(outs)} output and {len(ins)} input JACK ports, {channels} of "
            "each are needed; open the stream (through the JACK host API) before wiring"
        )
    pairs = list(zip(outs[:channels], ins[:channels], strict=True))
    for src, dst in pairs:
        connect(src, dst)
    return pairs
