"""Tank runs from Python (a notebook, a script), with the estimates as they come.

Example::

    from hil.experiments import api

    outcome, summary = api.run(on_estimates=print)      # the built-in simulated tank
    for item in api.iterate("my-tank.toml"):            # estimates and status, live
        if isinstance(item, api.Status):
            print(item.text)
        elif isinstance(item, api.Finished):
            print(item.summary["range_rmse_m"])
        else:
            plot(item.t_s, item.range_m)                 # an Estimate

:func:`run` blocks and calls back on the run's thread; :func:`iterate` runs it in a thread
and yields :class:`~hil.estimation.base.Estimate` s, :class:`Status` lines and, last, a
:class:`Finished`; leaving the loop early (``break``, an exception, a notebook's interrupt)
stops the run as Ctrl-C does. Both write the run folder as ``hil tank-run`` does (recording,
``summary.json``, ``estimates.csv``, figures); a recording reads back as arrays with
:meth:`hil.recording.RunRecording.table`.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hil.estimation.base import Estimate
from hil.experiments.experiment import DEFAULT_EXPERIMENT, Experiment, load_experiment
from hil.experiments.experiment import parse_experiment as _parse
from hil.experiments.tank_run import LiveView, RunOutcome, run_experiment


@dataclass(frozen=True)
class Status:
    """The run's status line (what ``hil tank-run`` shows live)."""

    text: str


@dataclass(frozen=True)
class Finished:
    """The end of a run: its outcome and summary (as ``summary.json``)."""

    outcome: RunOutcome
    summary: dict[str, Any]


class _CallbackView(LiveView):
    """The status line handed to a callback instead of a terminal."""

    def __init__(self, callback: Callable[[str], None] | None) -> None:
        super().__init__(enabled=callback is not None)
        self._callback = callback

    def update(self, text: str, *, force: bool = False) -> None:
        if self._callback is not None:
            self._callback(text)

    def close(self) -> None:
        pass


def experiment_of(experiment: Experiment | Path | str | None) -> Experiment:
    """An :class:`~hil.experiments.experiment.Experiment`: as given, read from a file
    (a path), parsed from TOML text (a string holding a newline), or the built-in
    simulated tank (None)."""
    if isinstance(experiment, Experiment):
        return experiment
    if experiment is None:
        return _parse(DEFAULT_EXPERIMENT)
    if isinstance(experiment, str) and "\n" in experiment:
        return _parse(experiment)
    return load_experiment(Path(experiment))


def run(
    experiment: Experiment | Path | str | None = None,
    *,
    folder: Path | None = None,
    on_estimates: Callable[[list[Estimate]], None] | None = None,
    on_status: Callable[[str], None] | None = None,
    stop: threading.Event | None = None,
    figures: bool = True,
    virtual_time: bool = False,
) -> tuple[RunOutcome, dict[str, Any]]:
    """Run an experiment (see :func:`experiment_of`) and write its folder; the outcome and
    summary. ``on_estimates``/``on_status`` are called on this thread as the run goes;
    setting ``stop`` stops it as Ctrl-C does; ``virtual_time`` runs the built-in simulated
    tank in this process on virtual time (deterministic, faster than real time). Refusals
    before anything moves or transmits raise :class:`~hil.errors.ConfigError`; later
    failures are in ``summary["error"]``."""
    from hil.experiments.run_report import write_report
    from hil.experiments.run_scoring import summarize, write_summary

    outcome = run_experiment(
        experiment_of(experiment),
        folder=folder,
        view=_CallbackView(on_status),
        on_estimates=on_estimates,
        stop=stop,
        virtual_time=virtual_time,
    )
    summary = summarize(outcome)
    write_summary(outcome, summary)
    if figures:
        write_report(outcome)
    return outcome, summary


def iterate(
    experiment: Experiment | Path | str | None = None,
    *,
    folder: Path | None = None,
    figures: bool = True,
    virtual_time: bool = False,
) -> Iterator[Estimate | Status | Finished]:
    """Run in a thread, yielding estimates and status lines as they come and a
    :class:`Finished` last; closing the iterator early stops the run (safely, as Ctrl-C)
    and waits for it. A refusal or error of the run is raised here. ``virtual_time`` as for
    :func:`run`."""
    items: queue.Queue[Any] = queue.Queue()
    stop = threading.Event()
    done = object()

    def put_all(batch: list[Estimate]) -> None:
        for estimate in batch:
            items.put(estimate)

    def body() -> None:
        try:
            outcome, summary = run(
                experiment,
                folder=folder,
                on_estimates=put_all,
                on_status=lambda text: items.put(Status(text)),
                stop=stop,
                figures=figures,
                virtual_time=virtual_time,
            )
            items.put(Finished(outcome, summary))
        except BaseException as exc:  # handed to the caller's thread
            items.put(exc)
        finally:
            items.put(done)

    thread = threading.Thread(target=body, name="hil-run", daemon=True)
    thread.start()
    try:
        while (item := items.get()) is not done:
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        thread.join()
