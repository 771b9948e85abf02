"""A private JACK server on the dummy driver (``jackd -d dummy``), started and stopped by this
process: the audio stack a simulated device runs on when no sound card is there.

The dummy driver runs in real time: one period every ``period / samplerate`` seconds of the
wall clock. It has no slower pace: its ``-w`` (wait) option, which reads like the wait between
periods, sets the period itself in jackd 2 (``period = wait x samplerate``, jack2's
``JackDummyDriver.cpp``), so this module never passes it.

By default the server runs synchronously (``--sync``): each period waits for every client to
finish (up to ``client_timeout_ms``) instead of dropping a late client's output. A client that
computes a simulation in Python on a busy machine is late now and then; with a sound card that
is an xrun, here it only delays the period, so the samples stay continuous and the clients'
streams stay in step, while the stream's pace against the wall clock slows for a while (the
dummy driver starts its timing afresh after a late period and reports it as an xrun). A
client that dates things on the wall clock maps them onto the stream through its callback's
stamps, not through the nominal rate. An asynchronous server (``synchronous=False``) behaves
as a sound card does: a late client is an xrun.

Clients find the server by name through ``JACK_DEFAULT_SERVER`` (``default`` when unset).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from hil.devices.audio.jack_ports import JackToolError
from hil.errors import ConfigError

#: The server name clients use when ``JACK_DEFAULT_SERVER`` is unset.
DEFAULT_SERVER_NAME = "default"
#: The JACK programs a dummy server and its wiring need.
JACK_TOOLS = ("jackd", "jack_lsp", "jack_connect")
#: Deadlock guard for the server to answer ``jack_lsp``: it answers within a second on a
#: quiet machine, tens of seconds on a badly overloaded one.
STARTUP_TIMEOUT_S = 60.0


def server_name() -> str:
    """The JACK server clients of this process connect to (``JACK_DEFAULT_SERVER``)."""
    return os.environ.get("JACK_DEFAULT_SERVER") or DEFAULT_SERVER_NAME


def missing_tools() -> list[str]:
    """The programs of :data:`JACK_TOOLS` not found on ``PATH`` (empty when JACK is there)."""
    return [tool for tool in JACK_TOOLS if shutil.which(tool) is None]


def server_answers(name: str) -> bool:
    """True when a JACK server called ``name`` answers ``jack_lsp``."""
    env = dict(os.environ, JACK_DEFAULT_SERVER=name, JACK_NO_START_SERVER="1")
    try:
        proc = subprocess.run(
            ["jack_lsp"], env=env, capture_output=True, text=True, timeout=30, check=False
        )
    except subprocess.TimeoutExpired:
        return False  # a busy machine: the caller asks again
    return proc.returncode == 0 and "system:" in proc.stdout


@dataclass(frozen=True)
class DummyServerSettings:
    """A dummy-driver server: sample rate (Hz), period (frames), how long a period waits for
    a late client (ms) before the server gives up on it, and whether periods wait for late
    clients at all (``synchronous``; False: a late client is an xrun, as on a sound card)."""

    samplerate: int
    period: int
    client_timeout_ms: int = 20_000
    synchronous: bool = True

    def __post_init__(self) -> None:
        if int(self.samplerate) != self.samplerate or not 1000 <= self.samplerate <= 768_000:
            raise ConfigError(
                "samplerate", self.samplerate, "a whole number of Hz in [1000, 768000]"
            )
        if self.period not in {2**k for k in range(4, 16)}:
            raise ConfigError("period", self.period, "a power of two from 16 to 32768 frames")

    def command(self, name: str) -> list[str]:
        """The ``jackd`` command line of this server, called ``name``.

        >>> " ".join(DummyServerSettings(192000, 256).command("lab"))
        'jackd --no-realtime --sync -t 20000 -n lab -d dummy -r 192000 -p 256'
        >>> " ".join(DummyServerSettings(192000, 256, synchronous=False).command("lab"))
        'jackd --no-realtime -n lab -d dummy -r 192000 -p 256'
        """
        sync = ["--sync", "-t", str(self.client_timeout_ms)] if self.synchronous else []
        return [
            "jackd", "--no-realtime", *sync, "-n", name,
            "-d", "dummy", "-r", str(self.samplerate), "-p", str(self.period),
        ]  # fmt: skip


class JackDummyServer:
    """``jackd -d dummy`` under ``name`` (default: :func:`server_name`), started by
    :meth:`start` and stopped by :meth:`close` (a context manager). Refuses to start when a
    server of that name already answers: two servers cannot share a name."""

    def __init__(self, settings: DummyServerSettings, name: str | None = None) -> None:
        self.settings = settings
        self.name = name or server_name()
        self._proc: subprocess.Popen[bytes] | None = None
        self._log: Path | None = None

    def start(self, timeout_s: float = STARTUP_TIMEOUT_S) -> JackDummyServer:
        """Start the server and wait until it answers; raises :class:`JackToolError` naming
        what is missing or what went wrong (with the server's last output)."""
        missing = missing_tools()
        if missing:
            raise JackToolError(
                f"{', '.join(missing)} not found; install JACK (Debian: apt-get install jackd2)"
            )
        if server_answers(self.name):
            raise JackToolError(
                f"a JACK server named {self.name!r} already runs; stop it, or set "
                "JACK_DEFAULT_SERVER to another name for this server and its clients"
            )
        fd, log = tempfile.mkstemp(prefix="jackd-", suffix=".log")
        os.close(fd)
        self._log = Path(log)
        env = dict(os.environ, JACK_NO_AUDIO_RESERVATION="1")
        with self._log.open("wb") as out:
            self._proc = subprocess.Popen(
                self.settings.command(self.name), stdout=out, stderr=subprocess.STDOUT, env=env
            )
        deadline = time.monotonic() + timeout_s
        while not server_answers(self.name):
            if self._proc.poll() is not None or time.monotonic() > deadline:
                tail = self.log_tail()
                self.close()
                raise JackToolError(
                    f"jackd {self.name!r} did not start within {timeout_s:g} s: {tail}"
                )
            time.sleep(0.05)  # polling a child process's readiness, not a test's timing
        return self

    def log_tail(self, chars: int = 2000) -> str:
        """The end of the server's output (empty once closed)."""
        if self._log is None or not self._log.exists():
            return ""
        return self._log.read_text(errors="replace")[-chars:]

    def close(self) -> None:
        """Stop the server (SIGTERM, then SIGKILL after 5 s)."""
        proc, self._proc = self._proc, None
        if proc is not None and proc.poll() is None:
            proc.terminate()
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if self._log is not None:
            self._log.unlink(missing_ok=True)
            self._log = None

    def __enter__(self) -> JackDummyServer:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
