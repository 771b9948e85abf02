"""The JACK device's lost-mid-run case of the every-device suite, as its own process.

``python -m tests.experiments.jack_lost_run EXPERIMENT FOLDER JACKD_PID`` runs the experiment
file in real time into FOLDER (its recording and ``summary.json``), stops the JACK server
(process JACKD_PID) with SIGTERM after the 30th estimate, prints the outcome as one JSON
line, and exits. Its own process because a
PortAudio stream whose JACK server died cannot be released: the run abandons it, and
PortAudio in that process cannot be re-initialised (the suite's process re-scans devices for
every served tank); its exit code shows the interpreter still exits.
"""

from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path

from hil.estimation.base import Estimate
from hil.experiments import api

LOSE_AFTER = 30  # estimates


def main(argv: list[str]) -> int:
    experiment, folder, jackd_pid = Path(argv[0]), Path(argv[1]), int(argv[2])
    seen: list[Estimate] = []

    def stop_server_after_30(estimates: list[Estimate]) -> None:
        if len(seen) < LOSE_AFTER <= len(seen) + len(estimates):
            # SIGTERM, never SIGKILL: a killed jackd leaves its entry in JACK's registry.
            os.kill(jackd_pid, signal.SIGTERM)
        seen.extend(estimates)

    outcome, _ = api.run(
        experiment, folder=folder, on_estimates=stop_server_after_30, figures=False
    )
    print(
        json.dumps(
            {
                "error": outcome.error,
                "interrupted": outcome.interrupted,
                "seen": len(seen),
                "folder": str(outcome.folder),
            }
        ),
        flush=True,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
