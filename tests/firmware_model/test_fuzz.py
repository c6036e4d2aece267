"""Random command streams (valid and not, plus line garbage) against the closed loop: the
firmware never raises, answers every command once, and keeps its output invariants."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from firmware_model.params import FirmwareParams, ServoParams
from serial_protocol.messages import (
    Ack,
    ClearFault,
    FaultInfo,
    FaultReport,
    Gains,
    GetFault,
    GetGains,
    GetLimits,
    GetStatus,
    Heartbeat,
    Hello,
    HelloReply,
    Limits,
    Loop,
    Move,
    Nack,
    Profile,
    SetEnable,
    SetGains,
    SetLimits,
    SetTelemetry,
    State,
    Status,
    Stop,
)

_any_float = st.one_of(
    st.floats(-3000.0, 3000.0),
    st.sampled_from([0.0, -1.0, float("nan"), float("inf"), -float("inf"), 1e9]),
)
_ids = st.integers(0, 5)  # few ids, so repeats (duplicates) happen


def _command():
    return st.one_of(
        st.builds(
            Move,
            cmd_id=_ids,
            target_deg=st.floats(-2.1e5, 2.1e5),
            v_max_dps=_any_float,
            a_max_dps2=_any_float,
            j_max_dps3=_any_float,
            profile=st.sampled_from(list(Profile)),
        ),
        st.builds(Stop, cmd_id=_ids, a_max_dps2=_any_float),
        st.builds(
            SetGains,
            cmd_id=_ids,
            loop=st.sampled_from(list(Loop)),
            kp=_any_float,
            ki=_any_float,
            kd=st.sampled_from([0.0, 0.1]),
        ),
        st.builds(
            SetLimits,
            cmd_id=_ids,
            v_max_dps=_any_float,
            a_max_dps2=_any_float,
            current_limit_a=st.floats(-1.0, 10.0),
            following_error_deg=_any_float,
        ),
        st.builds(ClearFault, cmd_id=_ids),
        st.builds(SetEnable, cmd_id=_ids, enable=st.booleans()),
        st.builds(SetTelemetry, cmd_id=_ids, decimation=st.integers(0, 5)),
        st.builds(GetStatus, cmd_id=_ids),
        st.builds(GetGains, cmd_id=_ids, loop=st.sampled_from(list(Loop))),
        st.builds(GetLimits, cmd_id=_ids),
        st.just(Hello()),
        st.builds(Heartbeat),
        st.builds(GetFault, cmd_id=_ids, bit=st.integers(0, 40)),
    )


@pytest.mark.parametrize("variant", ["float", "fixed", "batch"])
@settings(
    max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    script=st.dictionaries(st.integers(0, 79), st.lists(_command(), min_size=1, max_size=3)),
    garbage=st.dictionaries(st.integers(0, 79), st.binary(max_size=20), max_size=3),
)
def test_random_command_streams(make_bench, variant, script, garbage):
    if variant == "fixed":
        b = make_bench(FirmwareParams(servo=ServoParams(arithmetic="fixed")))
    else:
        b = make_bench(batch=2 if variant == "batch" else None)
    b.run(80, script, rx_raw=garbage)
    n_sent = sum(len(v) for v in script.values())
    replies = [m for m in b.received if isinstance(m, Ack | Nack | Status | Gains | Limits |
                                                   HelloReply | FaultInfo)]  # fmt: skip
    # A Heartbeat of the session is not answered.
    n_sent -= sum(isinstance(m, Heartbeat) for v in script.values() for m in v)
    # Garbage may corrupt a command's frame (then it is never answered) or hold a fake
    # Malformed frame (an extra NACK); without garbage every command is answered once.
    if not garbage:
        assert len(replies) == n_sent + b.auto_hellos
    duty = b.arr("duty").reshape(80, -1)[:, 0]  # member 0 in batch (the one replies describe)
    assert np.all(np.abs(duty) <= 1.0)
    np.testing.assert_allclose(duty * 3600, np.round(duty * 3600), atol=1e-9)
    state = b.arr("state").reshape(80, -1)[:, 0]
    off = (state == State.DISABLED) | (state == State.FAULT)
    assert np.all(duty[off] == 0.0)
    assert np.all((state == State.FAULT) == (b.arr("fault").reshape(80, -1)[:, 0] != 0))
    counters = b.fw.counters
    if variant == "batch":
        # Two identical members see identical inputs: they must stay identical.
        for key in ("pos_deg", "duty", "state", "fault"):
            np.testing.assert_array_equal(b.arr(key)[:, 0], b.arr(key)[:, 1])
        assert counters["faults"] == 2 * len(b.replies(FaultReport))
    else:
        assert counters["faults"] == len(b.replies(FaultReport))
    assert counters["tx_telemetry_dropped"] == 0 and counters["tx_replies_dropped"] == 0
