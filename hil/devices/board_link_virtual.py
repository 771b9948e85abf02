"""The board link on virtual time: :class:`VirtualTimeBoardLink`, no threads.

An in-process simulated board on a :class:`~hil.devices.clock.VirtualClock` needs no
reader or writer thread: at every tick of the clock the link's service reads the link and
hands it to the driver, feeds the DAC within the credit and sends a keepalive if due (the
work the threads of :class:`~hil.devices.board_link.ThreadedBoardLink` do), and the driver's
waits sleep on the clock, which runs the service meanwhile. Two runs of the same work see
the same instants and give the same bytes, however loaded the machine. A link lost on
virtual time stays lost (the driver records a DISCONNECT); nothing reconnects it.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from hil.acquisition import SampleRing
from hil.devices.board_link import READ_SIZE, BoardLink, LinkHooks
from hil.devices.board_log import LOG
from hil.devices.clock import VirtualClock
from hil.transports import (
    QuietTransport,
    Transport,
    TransportClosedError,
    TransportError,
    TransportTimeoutError,
)


class VirtualTimeBoardLink(BoardLink):
    """The link's work as a service of ``clock`` (see the module docstring); timeouts are
    virtual seconds."""

    def __init__(self, clock: VirtualClock, hooks: LinkHooks) -> None:
        super().__init__(clock, hooks)
        self._virtual = clock
        self._detach: Callable[[], None] | None = None
        #: The sample index :meth:`wait_for_samples` waits for (see :meth:`quiet_until_ns`).
        self._awaited_index: int | None = None
        #: The transport's own quiet time (:class:`~hil.transports.QuietTransport`), or None
        #: where its device does not say it (every tick then services the link).
        self._device_quiet: Callable[[int | None, int], int] | None = None

    def open(self, connect: Callable[[], None]) -> None:
        # Attached first: the handshake's waits sleep on the clock, which services the link.
        self._detach = self._virtual.attach(self._service, self.quiet_until_ns)
        try:
            connect()
        except BaseException:
            self.close()
            raise
        self._closing.clear()

    def connect(self, transport: Transport) -> None:
        self._device_quiet = (
            transport.quiet_until_ns if isinstance(transport, QuietTransport) else None
        )
        super().connect(transport)

    def close(self) -> None:
        self._closing.set()
        if self._detach is not None:
            self._detach()
            self._detach = None

    def wait(
        self,
        done: Callable[[], bool],
        timeout_s: float,
        what: str,
        progress: Callable[[], int] | None = None,
    ) -> None:
        """See :meth:`BoardLink.wait`; ``timeout_s`` is virtual seconds, slept on the clock
        (``progress`` is not needed: on virtual time nothing is starved of CPU)."""

        def settled() -> bool:
            refusal = self.hooks.refusal()
            if refusal is not None:
                raise refusal
            return done() or not self.up

        if not self._virtual.wait_until(settled, timeout_s):
            url = self.hooks.url()
            LOG.debug(
                "board %s: timed out after %s s of virtual time waiting for %s",
                url,
                timeout_s,
                what,
            )
            raise TransportTimeoutError(
                f"{url}: no {what} within {timeout_s} s of virtual time; the simulated"
                " board did not answer"
            )
        if not done():
            raise TransportClosedError(f"{self.hooks.url()}: link lost while waiting for {what}")

    def wait_for_samples(self, ring: SampleRing, end_index: int, timeout_s: float) -> bool:
        """See :meth:`BoardLink.wait_for_samples`; ``timeout_s`` is virtual seconds. While
        it waits, the service may skip the ticks on which the board only captures samples
        short of ``end_index`` (:meth:`quiet_until_ns`)."""
        self._awaited_index = end_index
        try:
            return self._virtual.wait_until(
                lambda: ring.end_index is not None and ring.end_index >= end_index, timeout_s
            )
        finally:
            self._awaited_index = None

    def _service(self) -> None:
        """One turn of the reader's and the writer's work: what the link holds read and
        handled, the DAC fed within the credit, a keepalive sent if due."""
        if not self.up or not self.pump_once():
            return
        try:
            while self.hooks.feed_dac():
                pass
            self.hooks.keepalive_if_due()
        except TransportError as error:
            self.lost(str(error))

    def quiet_until_ns(self) -> int | None:
        """Virtual time (ns) before which :meth:`_service` may be skipped, or None (every
        tick). Asked of a link that says how long its device has nothing to send but, while
        :meth:`wait_for_samples` waits, samples below the awaited index (the simulated
        board's ``quiet_until_ns``; with no index awaited, only while the board captures
        nothing): the skipped ticks would have read nothing, or their samples arrive, the
        same, at the next service, before the wait can end. A keepalive due, DAC samples to
        send within credit, or frames not yet written end the quiet."""
        quiet, awaited = self._device_quiet, self._awaited_index
        if quiet is None or not self.up or self.queued:
            return None
        if self.hooks.dac_pending():
            return None
        until = int(quiet(awaited, READ_SIZE))
        due = self.hooks.next_keepalive_s()
        if due is not None:
            # Due at the first tick whose time reaches it: never later than this.
            until = min(until, math.floor(due * 1e9) - 1)
        return until
