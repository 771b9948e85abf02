"""``hil watch``: serve a live view of a run recording to the browser.

Example::

    hil tank-run &                             # records runs/sim-towed-pass-.../run.h5
    hil watch runs/sim-towed-pass-*/run.h5 --open

The page follows the recording while it is written (the writer flushes at least once a
second) and shows a finished recording the same way; stop the server with Ctrl-C.
"""

from __future__ import annotations

import argparse
import sys
import webbrowser
from pathlib import Path
from typing import Any

# Internal field names -> the options that set them (hil.cli.main names them in errors).
OPTION_NAMES = {"recording": "RUN", "port": "--port", "host": "--host"}


def register(sub: Any) -> None:
    """Add the ``watch`` sub-command."""
    p: argparse.ArgumentParser = sub.add_parser(
        "watch",
        help="live view of a run recording in the browser (range, speed, alarms)",
        description="Serve a web page showing a run recording (run.h5): range and speed "
        "estimates against the truth from the stage telemetry (m, m/s vs receive time in s), "
        "the decoded codeword of each estimate against the true hop boundaries, board and "
        "stage status, events with alarms highlighted, and counts. The page polls every "
        "0.5 s, so it follows a recording that hil tank-run is still writing (read as an "
        "SWMR reader: what the writer last flushed, at most 1 s old) and shows a finished "
        "one the same way. run.h5 holds no codeword sums: --map computes the time–codeword "
        "map in the server from the recorded samples. Prints the page's URL; stop with "
        "Ctrl-C. The page loads nothing from the internet.",
    )
    p.add_argument("recording", type=Path, metavar="RUN", help="run recording (run.h5)")
    p.add_argument(
        "--port",
        type=int,
        default=0,
        help="TCP port to serve on; 0 picks a free one (default: 0)",
    )
    p.add_argument(
        "--host",
        default="127.0.0.1",
        help="address to listen on; 0.0.0.0 serves other machines too (default: 127.0.0.1)",
    )
    p.add_argument("--open", action="store_true", help="open the page in the default browser")
    p.add_argument(
        "--map",
        action="store_true",
        help="also compute the time–codeword map from the recorded samples (the live GCAS "
        "receiver with its recorded settings, run in the server; about half a core for a "
        "tank-audio run, so off by default)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Execute ``hil watch``; return the exit status."""
    from hil.errors import ConfigError
    from hil.watch import WatchData, WatchServer

    if not 0 <= args.port <= 65535:
        raise ConfigError("port", args.port, "0..65535 (0: a free port)")
    from hil.recording.reader import probe_structure

    probe_structure(args.recording)
    data = WatchData.open(args.recording, live_map=args.map)
    try:
        server = WatchServer(data, args.host, args.port)
    except OSError as exc:
        import errno
        import socket

        data.close()
        if isinstance(exc, socket.gaierror) or exc.errno == errno.EADDRNOTAVAIL:
            # The host is at fault (no such name, not an address of this machine): not the port.
            raise ConfigError(
                "host",
                args.host,
                "a name or address of this machine",
                f"cannot listen there: {exc.strerror}; use 127.0.0.1 (this machine only) or"
                " 0.0.0.0 (every interface)",
            ) from None
        raise ConfigError(
            "port", args.port, "a free port on " + args.host, f"cannot listen: {exc.strerror}"
        ) from None
    print(f"watching {args.recording} at {server.url}  (Ctrl-C to stop)", flush=True)
    if args.open:
        webbrowser.open(server.url)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        print("stopped", file=sys.stderr)
    finally:
        server.close()
    return 0
