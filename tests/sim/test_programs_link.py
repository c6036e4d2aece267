"""A motion program sent by ``BoardClient`` through the emulated UART to the full simulated
bench (paper_bench.toml, compiled tick): flow control with more blocks than the queue
holds, the program executed in order to its last target, hold / resume and abort."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from firmware_model.programs import QUEUE_CAPACITY
from serial_protocol.host import BoardClient
from serial_protocol.messages import Ack, Nack, QueueState, QueueStatus, State
from sim.config import load_bench
from sim.loop import Simulation
from sim.simlink import SimulatedLink

BENCH = Path(__file__).resolve().parents[2] / "bench_configs" / "paper_bench.toml"


def client() -> tuple[Simulation, BoardClient]:
    sim = Simulation(load_bench(BENCH), seed=1)
    return sim, BoardClient(SimulatedLink(sim, ticks_per_poll=5), ack_timeout_s=30.0)


def test_send_program_with_flow_control_runs_more_blocks_than_the_queue_holds():
    sim, c = client()
    assert isinstance(c.set_enable(True), Ack)
    # 40 blocks (> 32): a forward sweep in 1-deg steps, then back
    blocks = [(float(k + 1), 60.0, 0.0) for k in range(30)]
    blocks += [(30.0 - 3.0 * (k + 1), 90.0, 0.0) for k in range(10)]
    last = c.send_program(blocks, poll_s=0.0)
    assert isinstance(last, QueueStatus), last
    assert last.free_slots + last.queued == QUEUE_CAPACITY
    st = c.wait_status(lambda s: s.state is State.HOLDING, timeout_s=60.0, interval_s=0.0)
    assert st is not None and st.state is State.HOLDING
    assert abs(st.target_deg - 0.0) < 1e-3 and abs(st.pos_deg) < 0.05
    done = c.queue_status()
    assert isinstance(done, QueueStatus)
    assert (done.state, done.queued, done.done) == (QueueState.EMPTY, 0, 40)
    assert not c.fault_reports


def test_hold_resume_and_abort_over_the_link():
    sim, c = client()
    c.set_enable(True)
    c.send_program([(20.0, 60.0, 0.0), (40.0, 60.0, 0.0)])
    c.collect(0.0)
    held = c.hold()
    assert isinstance(held, QueueStatus) and held.state is QueueState.HELD
    st = c.wait_status(lambda s: s.state is State.HOLDING, timeout_s=60.0, interval_s=0.0)
    assert st is not None and st.pos_deg < 40.0
    resumed = c.resume()
    assert isinstance(resumed, QueueStatus) and resumed.state is QueueState.RUNNING
    aborted = c.abort()
    assert isinstance(aborted, QueueStatus) and aborted.state is QueueState.EMPTY
    st = c.wait_status(lambda s: s.state is State.HOLDING, timeout_s=60.0, interval_s=0.0)
    assert st is not None and st.target_deg < 40.0
    # slow reversals (10 s each): none finishes while the queue fills
    full = [c.queue_segment(10.0 * (k % 2), 1.0) for k in range(1, QUEUE_CAPACITY + 2)]
    assert all(isinstance(r, QueueStatus) for r in full[:-1])
    assert isinstance(full[-1], Nack) and "queue is full" in c_text(full[-1])
    assert np.isfinite(st.pos_deg)


def c_text(nack: Nack) -> str:
    from serial_protocol.host import nack_text

    return nack_text(nack)


def test_the_board_heartbeat_carries_the_free_queue_slots():
    """Flow control without asking (#14 §1): every ``BoardHeartbeat`` says how many blocks
    the queue can take now; it follows the queue as it fills and as blocks finish."""
    sim, c = client()
    c.set_enable(True)

    def next_heartbeat():
        c.last_heartbeat = None
        hb = c.wait_for(lambda m: type(m).__name__ == "BoardHeartbeat", timeout_s=60.0)
        assert hb is not None
        return hb

    assert next_heartbeat().queue_free == QUEUE_CAPACITY
    # slow blocks (a 1 deg/s crawl): none finishes before the next heartbeat
    for k in range(5):
        assert isinstance(c.queue_segment(0.5 * (k + 1), 1.0), QueueStatus)
    assert next_heartbeat().queue_free == QUEUE_CAPACITY - 5
    c.abort()
    assert next_heartbeat().queue_free == QUEUE_CAPACITY
