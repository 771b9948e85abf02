"""Whether an output can be written, checked before the work that produces it.

Every command that writes a file or a folder (a run folder, ``--out``, ``--csv``, ``--map``,
a WAV, a calibration store, a log file) checks it here first, so an unwritable output is
refused in one line (:class:`~hil.errors.ConfigError`, exit status 2) before anything runs,
instead of failing with a traceback after minutes of work. The check is an attempt, not a
guess from permission bits: the folder is created if needed and a probe file is created and
removed in it (``root`` ignores permission bits; a read-only mount does not).
"""

from __future__ import annotations

import errno
import os
import threading
from pathlib import Path

from hil.errors import ConfigError

#: The name a file output gives for standard output.
STDOUT = "-"


def _cannot_create(option: str, path: Path, exc: OSError) -> ConfigError:
    """The refusal of a folder ``option`` names that this user cannot create."""
    return ConfigError(
        option,
        str(path),
        "a folder this user can create",
        f"cannot create it ({_why(exc)}): choose a writable place",
    )


def _why(exc: OSError) -> str:
    return exc.strerror or type(exc).__name__


def writable_folder(path: Path, option: str) -> Path:
    """``path`` as a folder files can be written into, created (with its parents) if
    missing; ``option`` names it in the refusal (``"--out"``, ``"run.output_dir"``).

    >>> import tempfile
    >>> base = Path(tempfile.mkdtemp())
    >>> writable_folder(base / "a" / "b", "--out") == base / "a" / "b"
    True
    >>> (base / "f").write_text("x")
    1
    >>> writable_folder(base / "f", "--out")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: --out = '.../f' is not allowed: must be a folder; it is a file: ...
    """
    if path.exists() and not path.is_dir():
        raise ConfigError(option, str(path), "a folder", "it is a file: choose a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _cannot_create(option, path, exc) from None
    probe = path / f".hil-write-probe-{os.getpid()}"
    try:
        fd = os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600)
        os.close(fd)
        probe.unlink()
    except OSError as exc:
        raise ConfigError(
            option,
            str(path),
            "a folder this user can write",
            f"cannot write there ({_why(exc)}): choose a writable folder",
        ) from None
    return path


def writable_file(path: Path, option: str, *, make_folder: bool = True) -> Path:
    """``path`` as a file that can be (over)written: not a folder, in a writable folder
    (created if missing, or with ``make_folder=False`` a FileNotFoundError naming ``path``),
    writable itself if it exists; ``-`` (standard output) passes.

    >>> import tempfile
    >>> base = Path(tempfile.mkdtemp())
    >>> writable_file(base / "new" / "est.csv", "--csv").name
    'est.csv'
    >>> writable_file(base, "--csv")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: --csv = '...' is not allowed: must be a file; it is a folder: ...
    """
    if str(path) == STDOUT:
        return path
    if path.is_dir():
        raise ConfigError(option, str(path), "a file", "it is a folder: give a file name inside it")
    if path.exists():
        if not os.access(path, os.W_OK) or not _opens_for_append(path):
            raise ConfigError(
                option,
                str(path),
                "a file this user can write",
                "it is read-only: choose another file or make it writable",
            )
        return path
    folder = path.parent if str(path.parent) else Path(".")
    if not make_folder and not folder.exists():
        raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), str(path))
    writable_folder(folder, option + " (its folder)")
    return path


def _opens_for_append(path: Path) -> bool:
    try:
        with path.open("ab"):
            return True
    except OSError:
        return False


#: The file that marks a folder as claimed (it holds the claiming PID): created exclusively,
#: so of two commands started at once into the same folder exactly one gets it. It stays: a
#: folder once claimed reads as used.
CLAIM = ".hil-claim"

#: Folders this process holds (resolved path -> claims not yet released): a command and the
#: run it starts claim the same folder, the second claim passes while the first is held.
_HELD: dict[Path, int] = {}
_HELD_LOCK = threading.Lock()


def claim_output_folder(
    path: Path, option: str, may_hold: frozenset[str] = frozenset(), holds: str = "output"
) -> Path:
    """``path`` claimed for this process's output: created if missing, else an empty folder
    (but for the names in ``may_hold``); refused (ConfigError) when it holds anything else
    (``holds`` says what: "a run"), is a file, cannot be written, or another process
    claimed it first. The claim is
    atomic (an exclusive create of :data:`CLAIM` holding the PID): of two commands started
    at once into one folder, one runs and the other is refused before it does anything.
    Claiming it again while this process holds it (a command, then the run it starts) passes;
    :func:`release_output_folder` ends a claim, after which the folder reads as used.

    >>> import tempfile
    >>> out = Path(tempfile.mkdtemp()) / "sim"
    >>> claim_output_folder(out, "--out") == claim_output_folder(out, "--out")
    True
    >>> release_output_folder(out); release_output_folder(out)
    >>> claim_output_folder(out, "--out")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    hil.errors.ConfigError: --out = '.../sim' is not allowed: must be a new or empty folder; ...
    """
    held = path.resolve()
    with _HELD_LOCK:
        if _HELD.get(held, 0) > 0:
            _HELD[held] += 1
            return path
    used = ConfigError(
        option,
        str(path),
        "a new or empty folder",
        f"it holds {holds} already, which is never overwritten; choose another folder",
    )
    if path.exists() and not path.is_dir():
        raise ConfigError(option, str(path), "a new or empty folder", "it is a file, not a folder")
    if not path.exists():
        writable_folder(path.parent, f"{option} (its parent folder)")
        try:
            path.mkdir()
        except FileExistsError:
            pass  # made by another process just now: the claim below decides
        except OSError as exc:
            raise _cannot_create(option, path, exc) from None
    marker = path / CLAIM
    if any(p.name not in may_hold for p in path.iterdir()):
        raise used
    try:
        fd = os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
    except FileExistsError:
        raise used from None
    except OSError as exc:
        raise ConfigError(
            option,
            str(path),
            "a folder this user can write",
            f"cannot write there ({_why(exc)}): choose a writable folder",
        ) from None
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(f"{os.getpid()}\n")
    with _HELD_LOCK:
        _HELD[held] = 1
    return path


def release_output_folder(path: Path) -> None:
    """End one claim of ``path`` by this process (:func:`claim_output_folder`); once all are
    ended, claiming it again is refused like any used folder."""
    held = path.resolve()
    with _HELD_LOCK:
        left = _HELD.get(held, 0) - 1
        if left > 0:
            _HELD[held] = left
        else:
            _HELD.pop(held, None)
