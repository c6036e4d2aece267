"""The servo tick of the simulation, compiled end to end: many ticks in one call.

``run_ticks`` runs the ticks of ``Simulation.step`` for the project's firmware, in the order
of ``sim/loop.py``'s docstring, for N members:

1. ``TOP``: the plant state at the sampling instant into the log; the encoder reading
   (with its injected faults and SPI frames, ``sim.encoder.inject_faults``, and the
   firmware's check of the frames, ``firmware_model.as5048.check_reading``, while a fault
   is injected); the observer (``law.estimate``).
2. ``SERVO``: the brake countdown, the back-EMF check, the setpoint, the position and
   velocity loops, the trip screen (``firmware_model.tick.servo_stage``).
3. ``TICKUP``, ``TRANSMIT``: the firmware's tick count, the ``BoardHeartbeat`` when one is
   due (``firmware_model.tick.frame_heartbeat``) and the telemetry frame
   (``firmware_model.tick.frame_telemetry``) into the TX FIFO, as ``Firmware._transmit``
   does with no reply queued.
4. ``CURRENT``, ``BRIDGE``, ``PLANT`` (``current_loop_multiple`` times): the ADC, the
   current loop and its over-current screen (``firmware_model.tick.current_stage``), the
   bridge (kept on for a member braking after a trip, ``firmware_model.safety.brake_enable``),
   the plant step (``sim.plant_kernel.step_members``; with ``[supply] bus_model``
   ``sim.supply.step_period``: in sub-steps coupled to the bus).
5. ``LOG``: the firmware's signals and the bridge voltage into the log row; the TX line
   shifts out one tick of bytes (``serial_protocol.uart.pace``).

Python keeps what is rare and rich. ``run_ticks`` returns at an event with a ``STOP_*`` code,
its place kept in ``ctx`` (tick, stage, current-loop period, plant member); the caller
(``Simulation._run_compiled``) handles the event and calls again to resume:

=================  ===========================================================
``STOP_END``       the requested ticks are done
``STOP_RX``        bytes reached the board (or the silence rule fires): the receive side
``STOP_TRIP``      the trip screen hit: ``Firmware._check`` latches the trips
``STOP_TRANSMIT``  replies are queued, a heartbeat is due that the compiled tick does not
                   frame (the program queue or the point stream is active, or it does
                   not fit), or no compiled framer: ``Firmware._transmit``
``STOP_OC``        an over-current trip: ``Firmware._trip``
``STOP_MODE``      the plant met a mode without matrices: ``Plant._load``
``STOP_NOISE``     a block of noise draws is used up: draw the next block
``STOP_UART``      the PC -> board line is busy: move its bytes (``EmulatedUart``)
``STOP_HEAT``      a winding reached a temperature without plant tables:
                   ``sim.thermal.Heat.make_group``
``STOP_BOOT``      the first reading (``flags[F_BOOT]``), before the observer runs:
                   ``Firmware._boot`` (resets the law on it, enables if configured)
=================  ===========================================================
"""

from __future__ import annotations

import numpy as np

from firmware_model import as5048, safety
from firmware_model.kernel_cache import kernel
from firmware_model.laws import dispatch as law_steps
from firmware_model.laws.layout import (
    C_BUS_ADC,
    C_CAL_LEFT,
    P_DUTY,
    P_EMF_RISE,
    P_IMEAS,
    P_IREF,
    P_POS,
    P_R_RISE,
    P_VEL,
    P_VEL_RAW,
)
from firmware_model.tick import (
    FI_DECIMATION,
    FI_HEARTBEAT,
    FI_LINK,
    FI_SEQ,
    FI_TICK,
    FI_TX_BYTES,
    FI_TX_DROPPED,
    FI_TX_FRAMES,
    FS_BRAKE_CAP,
    FS_SP_ACC,
    FS_SP_POS,
    FS_SP_VEL,
    SF_BUS_TICKS,
    bus_mv,
    current_stage,
    frame_heartbeat,
    frame_telemetry,
    live_state,
    member_state,
    servo_stage,
    state_of,
)
from serial_protocol import uart
from sim.bridge import apply_bridge, read_adc, switching
from sim.encoder import _read, inject_faults
from sim.plant_kernel import step_members
from sim.supply import read_bus_adc, step_period
from sim.thermal import heat_advance, heat_groups

__all__ = ["run_ticks"]

(
    STOP_END, STOP_RX, STOP_TRIP, STOP_TRANSMIT, STOP_OC, STOP_MODE, STOP_NOISE, STOP_UART,
    STOP_HEAT, STOP_BOOT,
) = range(10)  # fmt: skip
TOP, ESTIMATE, SERVO, TICKUP, TRANSMIT, CURRENT, BRIDGE, PLANT, LOG = range(9)
# ctx: where the run is and what it owes the caller.
(
    CX_K, CX_STAGE, CX_PERIOD, CX_MEMBER, CX_TXLEN, CX_SHIFTED, CX_PENDING, CX_ENC_ROW,
    CX_ADC_ROW, CX_EVENTS, CX_NEED_GROUP, CX_NEED_MODE, CX_KNOWN, CX_FLIP,
) = range(14)  # fmt: skip
N_CX = 14
# flags: what the caller says about this run.
(
    F_REPLIES, F_RX_PRESENT, F_RX_ACTIVE, F_FRAMER, F_KEEP, F_FIFO, F_FRAME_BYTES,
    F_ENC_NOISY, F_ADC_NOISY, F_SILENCE_AT, F_ENC_FAULT, F_BOOT,
) = range(12)  # fmt: skip
N_F = 12

_pace = kernel(uart.pace)
# servo_stage inlined into the tick (numba IR; one source, Firmware.servo_tick calls the plain
# one): called, it cost ~0.1 us of a ~0.8 us N = 1 tick (its ~10 array arguments and tuple;
# a longer sf tuple once doubled the cost, docs/benchmarks.md "heat"); +2.5 s of CPU of a cold
# compile of ~16 s.
_servo_stage = kernel(inline="always")(servo_stage.py_func)


@kernel(inline="always")
def _queued(ctx, fi, at, end):
    """A frame written into the TX buffer at ``txbuf[at:end]``: the buffer's end, the bytes
    owed to the line, the sequence number and the firmware's TX counters move on."""
    ctx[CX_TXLEN] = end
    ctx[CX_PENDING] += end - at
    fi[FI_SEQ] = (fi[FI_SEQ] + 1) & 0xFF
    fi[FI_TX_FRAMES] += 1
    fi[FI_TX_BYTES] += end - at


@kernel
def _log_plant(plog, k, x, consts):
    """Log row ``k`` of the plant's columns (``sim.loop.PLANT_LOG``, ``plog`` ``(5,
    capacity, N)``) from the states ``x`` (``(N, 5)``), as the log shows them: ``consts``
    ``(3, N)``: degrees per radian of the axis, the total ratio, degrees per radian
    (``Simulation._log_plant``'s numpy arithmetic)."""
    for j in range(x.shape[0]):
        pos = x[j, 1]
        plog[0, k, j] = pos * consts[0, j]
        plog[1, k, j] = x[j, 2] * consts[0, j]
        plog[2, k, j] = (pos / consts[1, j] - x[j, 3]) * consts[2, j]
        plog[3, k, j] = pos
        plog[4, k, j] = x[j, 0]


# nogil: the rest of a block of encoder noise is drawn on a thread meanwhile (Encoder.refill).
@kernel(nogil=True)
def run_ticks(
    k_end, ctx, credit, flags, law, fw, sim, plant, logs, txbuf, tables, enc_faults,
):  # fmt: skip
    """Run ticks until ``k_end`` or an event (see the module docstring); returns the
    ``STOP_*`` code. ``credit`` (``(1,)``) is the TX line's banked credit.

    ``law = (P, C, S, G, K)``: the control law's state (its arithmetic picks its steps);
    ``fw = (fs, fi, enabled, fault, oc_ticks, prof, en_now, fault_flags, sf)`` (``sf``:
    ``firmware_model.tick.servo_stage``'s); ``sim = (x0, x1, dt_s,
    multiple, enc_params, enc_block, adc_params, adc_block, adc_full, bridge_params,
    sense_sign, volt, duty, enable, counts, adc, bytes_per_s, values)`` (``values``: scratch
    for a telemetry frame's six float fields); ``plant = (keys, group,
    slots, phis, rates, consts, levels, budget, bus, heat, sweep)`` (``bus``:
    ``sim.supply.Bus``'s arrays, ``heat``: ``sim.thermal.Heat``'s, ``sweep``: the plant
    step's scratch, ``sim.plant_kernel.step_members``); ``logs = (plant (5, capacity, N): the
    columns of ``sim.loop.PLANT_LOG``, signals (11 arrays of (capacity, N), the setpoint's
    three (capacity, 1)), voltage, bus_v, winding_c ((0, N) when constant), plant_consts
    (3, N): degrees per radian of the axis, the total ratio, degrees per radian)``;
    ``tables``: ``(firmware_model.tick.TABLES, HEARTBEAT_TABLES)``, the framers' tables;
    ``enc_faults``: ``Encoder.fault_args`` (used while ``flags[F_ENC_FAULT]``)."""
    P, C, S, G, K = law
    fs, fi, enabled, fault, oc_ticks, prof, en_now, fault_flags, sf = fw
    brake_ticks, diag_ticks, diag_errors = sf[3], sf[4], sf[5]
    bus_ticks = sf[SF_BUS_TICKS]
    enc_fault, frozen_counts, lcg, angle_frames, diag_frames = enc_faults
    x0, x1, dt_s, multiple, enc_params, enc_block, adc_params, adc_block = sim[:8]
    adc_full, bridge_params, sense_sign, volt, duty, enable, counts, adc, bps, values = sim[8:]
    keys, group, slots, phis, rates, consts, levels, budget, bus, heat, sweep = plant
    plog, signals, voltage, bus_log, winding_log, plant_consts = logs
    heat_on = heat[0].shape[0] > 0
    temps = heat[0]
    # The log columns as locals: an array taken from a tuple inside the member loop would
    # cost a reference count increment and decrement per member and column.
    sig0, sig1, sig2, sig3, sig4, sig5, sig6, sig7, sig8, sig9, sig10 = signals
    bus_v = bus[0]
    latency, offset, enc_noise, counts_per_rad, counts_per_rev, enc_inl = enc_params
    a_per_lsb, adc_noise, sense_table = adc_params
    pwm = (duty, volt, sense_table)
    arr, supply_v, shifts = bridge_params
    n = x0.shape[0]
    no_draw = duty[:0]  # no noise draws (a view: the kernel allocates nothing)
    keep = flags[F_KEEP] != 0
    frame_bytes = flags[F_FRAME_BYTES]
    # Without the bus model the bus ADC reads the supply's voltage: the same counts every
    # period, read once a call (nothing else writes C_BUS_ADC in the compiled tick).
    bus_fixed = bus_v.shape[0] == 0
    bus_read = False
    tel_tables, hb_tables = tables
    while True:
        k = ctx[CX_K]
        stage = ctx[CX_STAGE]
        x = x1 if ctx[CX_FLIP] else x0
        xn = x0 if ctx[CX_FLIP] else x1
        if stage == TOP:
            if k >= k_end:
                return STOP_END
            draw = no_draw
            if flags[F_ENC_NOISY]:
                if ctx[CX_ENC_ROW] >= enc_block.shape[0]:
                    return STOP_NOISE
                draw = enc_block[ctx[CX_ENC_ROW]]
                ctx[CX_ENC_ROW] += 1
            if keep:
                # The plant's log columns (sim.loop.PLANT_LOG), as the log shows them.
                # Element loops, not slice assignments: those compile numba's shape-error
                # formatting (a tenth of the whole compile time) for an error that cannot
                # happen here.
                _log_plant(plog, k, x, plant_consts)
                # The bus voltage and the winding temperature where they change (else (0, N)).
                if bus_log.shape[0]:
                    for j in range(n):
                        bus_log[k, j] = bus_v[j]
                if winding_log.shape[0]:
                    for j in range(n):
                        winding_log[k, j] = temps[j, 0]
            _read(
                x, latency, offset, enc_noise, draw, counts_per_rad, counts_per_rev, counts, enc_inl
            )
            if flags[F_ENC_FAULT]:
                inject_faults(
                    counts, enc_noise, draw, counts_per_rev, enc_fault, frozen_counts, lcg,
                    angle_frames, diag_frames,
                )  # fmt: skip
                as5048.check_reading(
                    angle_frames, diag_frames, counts, C, diag_ticks, diag_errors,
                    flags[F_BOOT] == 0,
                )  # fmt: skip
            else:
                as5048.clear_diag(diag_ticks, diag_errors)
            stage = ESTIMATE
            if flags[F_BOOT]:
                ctx[CX_STAGE] = ESTIMATE
                return STOP_BOOT
        if stage == ESTIMATE:
            law_steps.estimate(counts, P, C, S, G, K)
            stage = SERVO
            silence = flags[F_SILENCE_AT] >= 0 and fi[FI_TICK] >= flags[F_SILENCE_AT]
            if flags[F_RX_PRESENT] or silence:
                ctx[CX_STAGE] = SERVO
                return STOP_RX
        if stage == SERVO:
            hit = _servo_stage(P, C, S, G, K, fs, fi, enabled, prof, sf)
            stage = TICKUP
            if hit:
                ctx[CX_STAGE] = TICKUP
                return STOP_TRIP
        if stage == TICKUP:
            fi[FI_TICK] += 1
            stage = TRANSMIT
        if stage == TRANSMIT:
            hb = fi[FI_HEARTBEAT]
            due = hb != 0 and fi[FI_TICK] % hb == 0
            if flags[F_REPLIES] or not flags[F_FRAMER] or (due and not fi[FI_LINK]):
                ctx[CX_STAGE] = CURRENT
                ctx[CX_PERIOD] = 0
                return STOP_TRANSMIT
            if due:  # the BoardHeartbeat, before this tick's telemetry (Firmware._transmit)
                at = ctx[CX_TXLEN]
                end = frame_heartbeat(
                    txbuf, at, flags[F_FIFO] - ctx[CX_PENDING], fi[FI_SEQ], fs, fi, enabled,
                    fault, fault_flags, C, hb_tables,
                )  # fmt: skip
                if end < 0:  # it does not fit: Firmware._transmit queues it
                    ctx[CX_STAGE] = CURRENT
                    ctx[CX_PERIOD] = 0
                    return STOP_TRANSMIT
                _queued(ctx, fi, at, end)
            dec = fi[FI_DECIMATION]
            if dec and (fi[FI_TICK] - 1) % dec == 0:
                free = flags[F_FIFO] - ctx[CX_PENDING]
                if frame_bytes <= free:
                    at = ctx[CX_TXLEN]
                    values[0], values[1] = fs[FS_SP_POS], fs[FS_SP_VEL]
                    values[2], values[3] = P[P_POS, 0], P[P_VEL, 0]
                    # The bridge is off for the next period if disabled, whatever the law said.
                    values[4] = P[P_IMEAS, 0]
                    values[5] = P[P_DUTY, 0] if enabled[0] else 0.0
                    end = frame_telemetry(
                        txbuf, at, fi[FI_SEQ], fi[FI_TICK] - 1, values,
                        state_of(0, fi, enabled, fault), fault[0],
                        fault_flags[0] if fault[0] else 0, bus_mv(C, fs), tel_tables,
                    )  # fmt: skip
                    if end < 0:  # NaN: frame refuses it, the firmware's Python says so
                        ctx[CX_STAGE] = CURRENT
                        ctx[CX_PERIOD] = 0
                        return STOP_TRANSMIT
                    _queued(ctx, fi, at, end)
                else:
                    fi[FI_TX_DROPPED] += 1
            stage = CURRENT
            ctx[CX_PERIOD] = 0
        while stage == CURRENT or stage == BRIDGE or stage == PLANT:
            if stage == CURRENT:
                draw = no_draw
                if flags[F_ADC_NOISY]:
                    if ctx[CX_ADC_ROW] >= adc_block.shape[0]:
                        ctx[CX_STAGE] = CURRENT
                        return STOP_NOISE
                    draw = adc_block[ctx[CX_ADC_ROW]]
                    ctx[CX_ADC_ROW] += 1
                read_adc(x, sense_sign, a_per_lsb, adc_noise, draw, adc_full, adc, pwm)
                if not (bus_fixed and bus_read):
                    read_bus_adc(bus, supply_v, adc_full, C[C_BUS_ADC])
                    bus_read = True
                for j in range(n):
                    en_now[j] = enabled[j]
                stage = BRIDGE
                if current_stage(adc, en_now, P, C, S, G, K, fs, fi, oc_ticks, bus_ticks):
                    ctx[CX_STAGE] = BRIDGE
                    return STOP_OC
            if stage == BRIDGE:
                safety.brake_enable(
                    en_now, brake_ticks, P[P_VEL], sf[1], sf[2], P[P_R_RISE], P[P_EMF_RISE],
                    fs[FS_BRAKE_CAP],
                )  # fmt: skip
                apply_bridge(
                    P[P_DUTY], en_now, C[C_CAL_LEFT], arr, supply_v, duty, enable, sense_sign,
                    volt,
                )  # fmt: skip
                switching(x, supply_v, shifts, duty, sense_sign, volt)
                stage = PLANT
                ctx[CX_MEMBER] = 0
            if stage == PLANT:
                if heat_on and heat_groups(x, heat, group, keys, consts):
                    ctx[CX_STAGE] = PLANT
                    return STOP_HEAT
                if bus_fixed:  # step_period's first line, without its call (~5 % of N = 1)
                    start, events, g, need = step_members(
                        x, duty, enable, keys, ctx[CX_KNOWN] != 0, ctx[CX_MEMBER], group, slots,
                        phis, rates, consts, levels, budget, xn, keys, np.int64(0), sweep,
                    )  # fmt: skip
                else:
                    start, events, g, need = step_period(
                        x, xn, duty, enable, keys, ctx[CX_KNOWN] != 0, ctx[CX_MEMBER], group,
                        slots, phis, rates, consts, levels, budget, bus, volt, sense_sign, sweep,
                    )  # fmt: skip
                ctx[CX_EVENTS] += events
                if need >= 0:
                    ctx[CX_STAGE] = PLANT
                    ctx[CX_MEMBER] = start
                    ctx[CX_NEED_GROUP] = g
                    ctx[CX_NEED_MODE] = need
                    return STOP_MODE
                if heat_on:
                    heat_advance(x, xn, heat)
                ctx[CX_KNOWN] = 1
                ctx[CX_FLIP] ^= 1
                x, xn = xn, x
                ctx[CX_PERIOD] += 1
                stage = CURRENT if ctx[CX_PERIOD] < multiple else LOG
        # LOG
        if keep:
            sp_pos, sp_vel, sp_acc = fs[FS_SP_POS], fs[FS_SP_VEL], fs[FS_SP_ACC]
            # The setpoint, shared by the batch: one value a tick.
            sig0[k, 0] = sp_pos
            sig1[k, 0] = sp_vel
            sig2[k, 0] = sp_acc
            # The motion state, read once: fi may alias the int64 log columns for the
            # compiler, which then re-read it for every member (~10 ns a member).
            live = live_state(fi)
            for j in range(n):
                sig3[k, j] = P[P_POS, j]
            for j in range(n):
                sig4[k, j] = P[P_VEL, j]
            for j in range(n):
                sig5[k, j] = P[P_VEL_RAW, j]
            for j in range(n):
                sig6[k, j] = P[P_IMEAS, j]
            for j in range(n):
                sig7[k, j] = P[P_IREF, j]
            for j in range(n):
                sig8[k, j] = P[P_DUTY, j]
            for j in range(n):
                sig9[k, j] = member_state(j, enabled, fault, live)
            for j in range(n):
                sig10[k, j] = fault[j]
            for j in range(n):
                voltage[k, j] = volt[j]
        shifted, credit[0] = _pace(credit[0], dt_s, bps, ctx[CX_PENDING])
        ctx[CX_PENDING] -= shifted
        ctx[CX_SHIFTED] += shifted
        ctx[CX_K] = k + 1
        ctx[CX_STAGE] = TOP
        if flags[F_RX_ACTIVE]:
            return STOP_UART
