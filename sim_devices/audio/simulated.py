"""A simulated full-duplex audio interface with the same contract as the PortAudio backend.

:class:`SimulatedDuplex` calls the user callback exactly as
:class:`~hil.devices.audio.portaudio_backend.SoundDeviceDuplex` does (see
:mod:`hil.devices.audio.contract`), from its own audio thread, block by block. What the ADC
captures is produced by a pluggable *world*: a callable that maps the block the DAC emits to
the block the ADC captures over the same sample indices. :class:`DigitalLoopbackWorld` (a
cable with a delay) is the one provided here; the tank acoustics plug into the same hook.

Timing model, all in samples of one clock (``t0`` = clock time at ``start()``):

- the callback for the block starting at sample index ``j`` runs at ``t0 + j / fs``;
- output sample ``n`` leaves the DAC at ``t0 + (n + blocksize) / fs`` (one block of output
  buffering), the world maps it to the ADC over the same instants;
- the ADC sample captured at index ``m`` reaches the callback ``io_delay_samples`` later,
  as input sample index ``m + io_delay_samples``.

So a loopback world with delay ``D`` gives a measured loopback latency of exactly
``io_delay_samples + D`` samples, whatever the block size. The clock is injected (any
:class:`~hil.devices.clock.Clock`): a manual clock (the default,
:class:`sim_devices.stage.clock.ManualClock`) jumps forward instantly so tests never sleep;
:class:`~hil.devices.clock.MonotonicClock` (also named ``RealtimeClock`` here) paces the
blocks at the real sample rate. On a
:class:`~hil.devices.clock.VirtualClock` (``virtual_time=``) there is no audio thread: the
blocks whose callback time has come run as a service of the clock, in the thread that lets
virtual time pass, so a whole run is held in one thread and is deterministic.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from hil.devices.audio.contract import (
    AudioCallback,
    BlockOutcome,
    CallbackRunner,
    FloatArray,
    StatusFlags,
    check_callback,
)
from hil.devices.audio.ring import ring_read, ring_write
from hil.devices.audio.settings import AudioSettings, SettingsView
from hil.devices.clock import Clock, MonotonicClock
from hil.errors import ConfigError
from sim_devices.stage.clock import ManualClock

if TYPE_CHECKING:
    from hil.devices.clock import VirtualClock


#: The wall clock, by the name this module gave it: blocks paced at the real sample rate.
RealtimeClock = MonotonicClock

__all__ = [
    "Clock",
    "DigitalLoopbackWorld",
    "ManualClock",
    "RealtimeClock",
    "SimulatedDuplex",
    "World",
]


class World(Protocol):
    """What the ADC captures, given what the DAC emits, one block at a time.

    ``world(output_block, sample_index, input_block)``: ``output_block`` (frames,
    channels_out) float32 holds the DAC samples at indices ``sample_index ...
    sample_index + frames - 1``; fill ``input_block`` (frames, channels_in) float32 in place
    with the ADC samples at those same indices. Called in the audio thread after the user
    callback, in sample order, so the same real-time rules apply (no blocking, no buffer
    allocation). A world with state may define ``reset()``; the backend calls it when a
    stream opens.
    """

    def __call__(
        self, output_block: FloatArray, sample_index: int, input_block: FloatArray, /
    ) -> None: ...


class DigitalLoopbackWorld:
    """A cable from each DAC channel to the same ADC channel, ``delay_samples`` late.

    Input channel ``k`` receives ``gain * output[k]`` delayed by ``delay_samples``; input
    channels with no matching output channel stay silent. The delay line grows only when a
    block longer than any before arrives (in practice: on the first block).

    Examples
    --------
    >>> import numpy as np
    >>> world = DigitalLoopbackWorld(delay_samples=2)
    >>> out = np.arange(1, 5, dtype=np.float32).reshape(4, 1)
    >>> inp = np.empty((4, 1), dtype=np.float32)
    >>> world(out, 0, inp); inp[:, 0].tolist()
    [0.0, 0.0, 1.0, 2.0]
    >>> world(out, 4, inp); inp[:, 0].tolist()
    [3.0, 4.0, 1.0, 2.0]
    """

    def __init__(self, delay_samples: int, gain: float = 1.0) -> None:
        if isinstance(delay_samples, bool) or not isinstance(delay_samples, int):
            raise ConfigError("delay_samples", delay_samples, "an integer >= 0 (samples)")
        if delay_samples < 0:
            raise ConfigError(
                "delay_samples", delay_samples, "an integer >= 0 (samples)", "a cable is causal"
            )
        if not np.isfinite(gain):
            raise ConfigError("gain", gain, "a finite number")
        self.delay_samples = delay_samples
        self.gain = np.float32(gain)
        self._ring = np.zeros((0, 0), dtype=np.float32)

    def reset(self) -> None:
        """Empty the cable (silence before the first output sample)."""
        self._ring.fill(0.0)

    def __call__(
        self, output_block: FloatArray, sample_index: int, input_block: FloatArray
    ) -> None:
        frames, ch_out = output_block.shape
        needed = self.delay_samples + frames
        if self._ring.shape[0] < needed or self._ring.shape[1] != ch_out:
            # Rare: only when a longer block arrives. Keep the history already written.
            grown = np.zeros((needed, ch_out), dtype=np.float32)
            if self._ring.shape[1] == ch_out and self._ring.shape[0]:
                keep = self._ring.shape[0]
                rows = np.arange(sample_index - keep, sample_index)
                grown[rows % needed] = self._ring[rows % keep]
            self._ring = grown
        ring_write(self._ring, sample_index, output_block)
        n = min(ch_out, input_block.shape[1])
        ring_read(self._ring[:, :n], sample_index - self.delay_samples, input_block[:, :n])
        if self.gain != 1.0:
            input_block[:, :n] *= self.gain
        input_block[:, n:] = 0.0


class SimulatedDuplex(SettingsView):
    """Simulated full-duplex interface: the contract of the real one, with a pluggable world.

    Parameters
    ----------
    settings:
        Sample rate, channels and block size (``device`` and ``latency`` are ignored).
    world:
        Maps each output block to the input block (see :class:`World`). Default: a digital
        loopback with no extra delay.
    io_delay_samples:
        Converter and buffer latency from ADC capture to the callback, in samples, at least
        ``settings.blocksize``; default ``2 * blocksize`` (what the JACK dummy server shows).
    clock:
        Time source; default a manual clock (no real-time waiting).
    virtual_time:
        Run the blocks as a service of this virtual clock instead of an audio thread (the
        module docstring); ``clock`` is then not given.
    xrun_schedule:
        Fault injection: ``{sample_index: flags}`` makes the block starting at that index
        report those :class:`~hil.devices.audio.contract.StatusFlags` (the data path stays
        exact). Indices must be multiples of the block size.
    xrun_capacity:
        Number of xrun events the log keeps.

    Examples
    --------
    >>> import numpy as np
    >>> from hil.devices.audio import play_record
    >>> s = AudioSettings(samplerate=48000, blocksize=64)
    >>> sim = SimulatedDuplex(s, DigitalLoopbackWorld(5), io_delay_samples=128)
    >>> pulse = np.zeros(400, dtype=np.float32); pulse[10] = 1.0
    >>> int(np.argmax(play_record(sim, pulse).recording[:, 0]))  # 10 + 128 + 5
    143
    """

    def __init__(
        self,
        settings: AudioSettings,
        world: World | None = None,
        *,
        io_delay_samples: int | None = None,
        clock: Clock | None = None,
        virtual_time: VirtualClock | None = None,
        xrun_schedule: Mapping[int, int] | None = None,
        xrun_capacity: int = 4096,
    ) -> None:
        if virtual_time is not None and clock is not None:
            raise ConfigError(
                "clock", clock, "None with virtual_time", "give only virtual_time: it is the clock"
            )
        self.settings = settings
        self.world: World = world if world is not None else DigitalLoopbackWorld(0)
        block = settings.blocksize
        delay = 2 * block if io_delay_samples is None else io_delay_samples
        if isinstance(delay, bool) or not isinstance(delay, int) or delay < block:
            raise ConfigError(
                "io_delay_samples",
                delay,
                f"an integer >= blocksize ({block}) samples",
                "a block's input can only hold samples captured before its callback runs",
            )
        self.io_delay_samples = delay
        if clock is None:
            clock = ManualClock()
        self.clock: Clock = clock
        self._virtual = virtual_time
        self._detach: Callable[[], None] | None = None
        self._t0 = 0.0
        self._ran = False
        schedule = dict(xrun_schedule or {})
        for index, flags in schedule.items():
            if index < 0 or index % block:
                raise ConfigError(
                    "xrun_schedule",
                    index,
                    f"sample indices >= 0 that are multiples of blocksize ({block})",
                    "xruns are reported per block, at the block's first sample",
                )
            schedule[index] = int(StatusFlags(flags))
        self._schedule = schedule
        self._xrun_capacity = xrun_capacity
        self._runner: CallbackRunner | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        #: Captured values the simulated converter clipped at ±1.0 full scale.
        self.adc_clipped_samples = 0
        self._unplugged = False

    @property
    def active(self) -> bool:
        """True while the audio thread runs (on virtual time: while the service is attached)."""
        if self._virtual is not None:
            return self._detach is not None
        return self._thread is not None and self._thread.is_alive()

    @property
    def start_time_s(self) -> float:
        """Clock time of the stream's start (s): the callback of the block at index ``j``
        runs at ``start_time_s + j / fs``, output sample ``n`` leaves the DAC at
        ``start_time_s + (n + blocksize) / fs``."""
        return self._t0

    @property
    def frames_processed(self) -> int:
        """Frames handed to the callback since the stream opened."""
        return 0 if self._runner is None else self._runner.sample_index

    @property
    def xruns(self) -> list[tuple[int, StatusFlags]]:
        """Xruns of the current stream as ``(sample_index, flags)``."""
        return [] if self._runner is None else self._runner.xruns.events()

    # --- life cycle ---
    def open(self, callback: AudioCallback) -> None:
        """Allocate every buffer and get ready to run ``callback`` (nothing runs yet)."""
        check_callback(callback)
        if self.active:
            raise RuntimeError("the simulated stream is running: stop() it before open()")
        block, ch_in, ch_out = self.blocksize, self.channels_in, self.channels_out
        self._runner = CallbackRunner(callback, self._xrun_capacity)
        self._indata = np.zeros((block, ch_in), dtype=np.float32)
        self._outdata = np.zeros((block, ch_out), dtype=np.float32)
        self._captured_block = np.zeros((block, ch_in), dtype=np.float32)
        self._captured = np.zeros((self.io_delay_samples + block, ch_in), dtype=np.float32)
        reset = getattr(self.world, "reset", None)
        if callable(reset):
            reset()
        self._thread = None
        self._ran = False

    def start(self) -> None:
        """Start the audio thread (on virtual time: attach the blocks to the clock)."""
        if self._runner is None:
            raise RuntimeError("open(callback) the stream before start()")
        if self._ran:
            raise RuntimeError("this stream already ran: open() it again to rerun")
        self._ran = True
        self._stop.clear()
        if self._virtual is not None:
            self._t0 = self._virtual.now()
            self._detach = self._virtual.attach(self._service)
            return
        self._thread = threading.Thread(target=self._run, name="sim-audio", daemon=True)
        self._thread.start()

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait until the stream ends; True if it has. Re-raises a callback exception.

        On virtual time nothing runs beside the caller: True once the stream ended."""
        if self._virtual is not None:
            if self._detach is not None:
                return False
        elif self._thread is not None:
            self._thread.join(timeout_s)
            if self._thread.is_alive():
                return False
        if self._runner is not None:
            self._runner.raise_pending()
        return True

    @property
    def abandoned(self) -> None:
        """None: a simulated stream always stops and closes as asked."""
        return None

    def describe(self) -> dict[str, Any]:
        """The simulated interface: its buffering (:attr:`io_delay_samples`) is its input
        latency (s)."""
        delay = int(self.io_delay_samples)
        return {
            "device": "simulated audio interface",
            "host_api": "simulated",
            "io_delay_samples": delay,
            "input_latency_s": delay / float(self.settings.samplerate),
        }

    def stop(self) -> None:
        """Stop after the current block. Re-raises a callback exception."""
        self._stop.set()
        self._end_service()
        self.wait()

    def close(self) -> None:
        """Stop and release the stream. Re-raises a callback exception not yet raised."""
        self.stop()

    def unplug(self) -> None:
        """Fault injection: the interface is pulled out; its stream ends before the next
        block, with no error from the callback (as a stream ends whose device vanished)."""
        self._unplugged = True

    def __enter__(self) -> SimulatedDuplex:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- audio thread (or virtual-time service) ---
    def _run(self) -> None:
        fs = self.samplerate
        clock = self.clock
        t0 = self._t0 = clock.now()
        assert self._runner is not None
        while not self._stop.is_set():
            clock.sleep_until(t0 + self._runner.sample_index / fs)
            if not self._block():
                return

    def _service(self) -> None:
        """Every block whose callback time has come, on the virtual clock."""
        assert self._virtual is not None and self._runner is not None
        due = math.floor((self._virtual.now() - self._t0) * self.samplerate + 1e-6)
        while self._detach is not None and self._runner.sample_index <= due:
            if not self._block():
                self._end_service()

    def _end_service(self) -> None:
        if self._detach is not None:
            self._detach()
            self._detach = None

    def _block(self) -> bool:
        """One block: input from the captured ring, the callback, the world; False once
        the stream ends (the callback completed or aborted, or raised)."""
        runner = self._runner
        assert runner is not None
        if self._unplugged:
            return False
        fs = self.samplerate
        block = self.blocksize
        delay = self.io_delay_samples
        indata, outdata = self._indata, self._outdata
        captured, captured_block = self._captured, self._captured_block
        t0 = self._t0
        j = runner.sample_index
        ring_read(captured, j - delay, indata)
        outdata.fill(0.0)
        outcome = runner.run_block(
            indata,
            outdata,
            block,
            t0 + (j - delay + block) / fs,
            t0 + (j + block) / fs,
            self._virtual.now() if self._virtual is not None else self.clock.now(),
            self._schedule.get(j, 0),
        )
        if outcome is BlockOutcome.ABORT:
            return False
        try:
            self.world(outdata, j, captured_block)
        except BaseException as exc:  # same rule as the callback: re-raised in wait()
            runner.error = exc
            return False
        # The converter: inputs beyond full scale clip at ±1.0, and are counted.
        over = int(np.count_nonzero(np.abs(captured_block) > 1.0))
        if over:
            self.adc_clipped_samples += over
            np.clip(captured_block, -1.0, 1.0, out=captured_block)
        ring_write(captured, j, captured_block)
        return outcome is not BlockOutcome.COMPLETE
