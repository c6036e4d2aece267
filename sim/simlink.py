"""A ``Link`` to a simulated board in this process: ``monitor sim://`` and the tests.

The PC's frames cross the emulated UART into the firmware exactly as over ``serve --pty``
(``Simulation.pc_write``/``pc_read``), and the board's bytes are decoded by the same
``Decoder``; only the operating system's pty is left out. Simulated time advances in
``poll``: either with the wall clock times ``speed`` (a live session), or by a fixed number
of ticks per call (``ticks_per_poll``: deterministic, whatever the machine's load; tests).
"""

from __future__ import annotations

import time
from typing import BinaryIO

from serial_protocol.frame import Decoder, DecoderStats, encode
from serial_protocol.messages import Malformed, Message

__all__ = ["SimulatedLink"]

#: At most this many ticks (0.1 s) are simulated in one burst when the host fell behind.
MAX_CATCH_UP_TICKS = 50


class SimulatedLink:
    """Talk to ``sim`` (a ``sim.loop.Simulation``, N = 1) through its emulated UART.

    Args:
        sim: the simulation (it is stepped by this link only).
        speed: simulated seconds per wall second when ``ticks_per_poll`` is None.
        ticks_per_poll: if given, each ``poll`` advances exactly this many ticks and does
            not wait.
        capture: a binary file object that receives a copy of every byte from the board.
    """

    def __init__(
        self,
        sim: object,
        speed: float = 1.0,
        ticks_per_poll: int | None = None,
        capture: BinaryIO | None = None,
    ):
        if not speed > 0:
            raise ValueError(f"speed = {speed!r}: must be > 0")
        if ticks_per_poll is not None and ticks_per_poll < 1:
            raise ValueError(f"ticks_per_poll = {ticks_per_poll!r}: must be >= 1")
        self.sim = sim
        self.speed = speed
        self.ticks_per_poll = ticks_per_poll
        self.decoder = Decoder()
        self.capture = capture
        self.bytes_in = 0
        self.bytes_out = 0
        self.frames_out = 0
        self._seq = 0
        self._start_wall_s = time.monotonic()
        self._start_tick = sim.tick  # type: ignore[attr-defined]

    @classmethod
    def open(
        cls,
        bench_path: str | None = None,
        speed: float = 1.0,
        seed: int = 0,
        capture: BinaryIO | None = None,
    ) -> SimulatedLink:
        """A fresh simulated bench (default ``bench_configs/paper_bench.toml``)."""
        import bench_configs
        from sim.config import load_bench
        from sim.loop import Simulation

        path = bench_path or bench_configs.path("paper_bench.toml")
        sim = Simulation(load_bench(path), seed=seed, keep_log=False)
        return cls(sim, speed=speed, capture=capture)

    def __enter__(self) -> SimulatedLink:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def send(self, msg: Message) -> None:
        """Frame ``msg`` and put it on the board's RX line."""
        data = encode(msg, self._seq)
        self._seq = (self._seq + 1) & 0xFF
        self.sim.pc_write(data)  # type: ignore[attr-defined]
        self.bytes_out += len(data)
        self.frames_out += 1

    def poll(self, timeout_s: float) -> list[Message | Malformed]:
        """Advance the simulation (see the class) and return the messages that arrived."""
        sim = self.sim
        if self.ticks_per_poll is not None:
            sim.step(self.ticks_per_poll)  # type: ignore[attr-defined]
        else:
            end_wall_s = time.monotonic() + max(0.0, timeout_s)
            dt_s = sim.dt_s  # type: ignore[attr-defined]
            while True:
                elapsed_s = (time.monotonic() - self._start_wall_s) * self.speed
                n = self._start_tick + int(elapsed_s / dt_s) - sim.tick  # type: ignore[attr-defined]
                # As serve does: a board that fell behind (a busy host) catches up in
                # bursts, so its clock keeps to the wall clock on average.
                n = min(n, MAX_CATCH_UP_TICKS)
                if n > 0:
                    sim.step(n)  # type: ignore[attr-defined]
                data = sim.pc_read()  # type: ignore[attr-defined]
                if data or time.monotonic() >= end_wall_s:
                    break
                time.sleep(min(0.002, max(0.0, end_wall_s - time.monotonic())))
            return self._decode(data)
        return self._decode(sim.pc_read())  # type: ignore[attr-defined]

    def _decode(self, data: bytes) -> list[Message | Malformed]:
        if not data:
            return []
        self.bytes_in += len(data)
        if self.capture is not None:
            self.capture.write(data)
        return self.decoder.feed(data)

    def stats(self) -> DecoderStats:
        """The receive decoder's counters."""
        return self.decoder.stats()

    def close(self) -> None:
        """Nothing to release (the simulation is garbage-collected)."""
