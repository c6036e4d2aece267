/*
 * tt_link: the board side of the turntable PC link, protocol version 2 (docs/protocol.md).
 *
 * Written for an STM32F103 (Cortex-M3, no FPU) from docs/protocol.md alone: no heap, fixed
 * buffers, C99, no floating-point arithmetic anywhere (f32 fields are moved as bit patterns
 * and checked for NaN/infinity on their exponent bits). Positions, velocities, currents and
 * duty are in wire units (int32 1e-4 deg, int32 1e-4 deg/s, int16 mA, int16 1e-4).
 *
 *   framing      tt_frame_encode(): sync, header check (CRC-8/SMBUS), CRC-32/ISO-HDLC
 *   receiving    tt_decoder: hunt, header check, CRC, resynchronisation one byte after a
 *                failed sync, the silence rule (tt_decoder_tick once per servo tick, or
 *                tt_decoder_silence after 20 ms without a byte), the receive counters
 *   commands     tt_decode_command(): a frame's payload into a tt_command, or the NACK code
 *                and field of section 3 ("good CRC, bad payload")
 *   answers      tt_encode_*(): every board -> PC message into a payload, then a frame
 */
#ifndef TT_LINK_H
#define TT_LINK_H

#include <stddef.h>
#include <stdint.h>

#define TT_PROTOCOL_VERSION 2u
#define TT_SYNC0 0xA5u
#define TT_SYNC1 0x5Au
#define TT_HEADER_BYTES 6u
#define TT_CRC_BYTES 4u
#define TT_OVERHEAD_BYTES (TT_HEADER_BYTES + TT_CRC_BYTES)
#define TT_MAX_PAYLOAD 64u
#define TT_MAX_FRAME (TT_MAX_PAYLOAD + TT_OVERHEAD_BYTES)
/* The silence rule: 20 ms, 10 servo ticks at 500 Hz. */
#define TT_RX_SILENCE_TICKS 10u
#define TT_NO_FIELD 0xFFu

/* ------------------------------------------------------------------ types and codes */

enum tt_type {
    TT_HELLO = 0x01, TT_HEARTBEAT = 0x02, TT_MOVE = 0x03, TT_STOP = 0x04,
    TT_SET_ENABLE = 0x05, TT_CLEAR_FAULT = 0x06, TT_SET_GAINS = 0x07, TT_GET_GAINS = 0x08,
    TT_SET_LIMITS = 0x09, TT_GET_LIMITS = 0x0A, TT_GET_STATUS = 0x0B, TT_SET_TELEMETRY = 0x0C,
    TT_GET_FAULT = 0x0D, TT_QUEUE_SEGMENT = 0x0E, TT_QUEUE_CONTROL = 0x0F,
    TT_STREAM_CONTROL = 0x10, TT_STREAM_POINTS = 0x11, TT_JOG = 0x12,
    TT_HELLO_REPLY = 0x81, TT_TELEMETRY = 0x82, TT_ACK = 0x83, TT_NACK = 0x84,
    TT_FAULT_REPORT = 0x85, TT_GAINS = 0x86, TT_LIMITS = 0x87, TT_STATUS = 0x88,
    TT_BOARD_HEARTBEAT = 0x89, TT_FAULT_INFO = 0x8A, TT_QUEUE_STATUS = 0x8B,
    TT_STREAM_STATUS = 0x8C
};

enum tt_nack_code {
    TT_OK = 0, TT_UNKNOWN_TYPE = 1, TT_BAD_LENGTH = 2, TT_NOT_FINITE = 3, TT_OUT_OF_RANGE = 4,
    TT_UNSTABLE_GAINS = 5, TT_FAULT_ACTIVE = 6, TT_DISABLED = 7, TT_NOT_A_COMMAND = 8,
    TT_NO_SESSION = 9, TT_STALE_SESSION = 10, TT_UNSUPPORTED_VERSION = 11, TT_TOO_HIGH = 12,
    TT_TOO_LOW = 13, TT_BUSY = 14, TT_TRAVEL = 15,
    TT_QUEUE_FULL = 16, TT_NO_STREAM = 17, TT_SENSE_OFFSET = 18
};

/* ------------------------------------------------------------------ checks and framing */

uint8_t tt_crc8(const uint8_t *p, size_t n);
uint32_t tt_crc32(const uint8_t *p, size_t n);
/* 1 if the f32 with these bits is finite (exponent bits not all ones). */
int tt_f32_finite(uint32_t bits);

/* Frame `len` payload bytes under `type` and `seq` into `out` (TT_MAX_FRAME bytes).
 * Returns the frame's length, or 0 if len > TT_MAX_PAYLOAD. */
size_t tt_frame_encode(uint8_t *out, uint8_t type, uint8_t seq, const uint8_t *payload,
                       size_t len);

/* ------------------------------------------------------------------ receiving */

typedef struct {
    uint32_t frames;           /* good header and CRC */
    uint32_t header_errors;    /* sync pairs with len > 64 or a bad header check */
    uint32_t crc_errors;       /* candidates with a good header and a bad CRC */
    uint32_t resyncs;          /* good frames after dropped bytes */
    uint32_t bytes_dropped;    /* bytes outside good frames */
    uint32_t seq_gaps;         /* good frames whose seq was not the last + 1 */
    uint32_t frames_missed;    /* sum of those gaps, modulo 256 each */
    uint32_t partial_discards; /* held bytes given up after a silence */
} tt_rx_stats;

/* Called for every good frame, in stream order; `payload` is valid during the call only. */
typedef void (*tt_frame_fn)(void *ctx, uint8_t type, uint8_t seq, const uint8_t *payload,
                            uint8_t len);

typedef struct {
    uint8_t buf[TT_MAX_FRAME]; /* a partial candidate frame, or a lone 0xA5 */
    uint8_t n;                 /* bytes held in buf */
    uint8_t hunting;           /* bytes were dropped since the last good frame */
    uint8_t have_seq;
    uint8_t last_seq;
    uint16_t idle_ticks;
    tt_rx_stats stats;
} tt_decoder;

void tt_decoder_init(tt_decoder *d);
/* Feed received bytes (any chunking: the output does not depend on it). */
void tt_decoder_feed(tt_decoder *d, const uint8_t *data, size_t n, tt_frame_fn fn, void *ctx);
/* The line was silent for the silence time: give up the held partial frame (a whole frame
 * still found in the held bytes is delivered). */
void tt_decoder_silence(tt_decoder *d, tt_frame_fn fn, void *ctx);
/* Once per servo tick, after that tick's tt_decoder_feed (if any bytes came): applies the
 * silence rule after TT_RX_SILENCE_TICKS ticks without a byte. */
void tt_decoder_tick(tt_decoder *d, int bytes_this_tick, tt_frame_fn fn, void *ctx);

/* ------------------------------------------------------------------ commands (PC -> board) */

typedef struct {
    uint8_t type;
    uint16_t cmd_id;
    uint16_t session;
    union {
        struct { uint8_t version_min, version_max; } hello;
        struct { int32_t target; uint32_t v_max, a_max, j_max; uint8_t profile; } move;
        struct { uint32_t a_max; } stop;
        struct { uint8_t enable; } set_enable;
        struct { uint8_t loop; uint32_t kp, ki, kd; } set_gains;
        struct { uint8_t loop; } get_gains;
        struct {
            uint32_t v_max, a_max, current_limit, following_error, over_current_trip;
            /* appended (an older PC's shorter payload: 0 = keep the board's) */
            uint32_t bus_over_voltage, bus_under_voltage, thermal_derate, thermal_trip;
            uint32_t brake_current_limit;
        } set_limits;
        struct { uint16_t decimation; } set_telemetry;
        struct { uint8_t bit; } get_fault;
        struct { int32_t target; uint32_t v_max, dwell; } queue_segment;
        struct { uint8_t action; uint32_t override_pct; } queue_control;
        struct { uint8_t action, interp; uint32_t period; uint8_t prefill; } stream_control;
        struct {
            uint32_t first_index;
            uint8_t count;
            int32_t pos[5]; /* 1e-4 deg */
            uint32_t vel[5];
        } stream_points;
        struct { uint32_t vel, a_max; uint16_t timeout_ms; } jog;
    } u; /* f32 fields as their bit patterns (tt_f32_finite, then memcpy into a float) */
} tt_command;

/* Decode a good frame's payload. Returns TT_OK, or the NACK code the board answers with
 * (TT_UNKNOWN_TYPE, TT_NOT_A_COMMAND, TT_BAD_LENGTH, TT_OUT_OF_RANGE) and sets *field to the
 * field index (TT_NO_FIELD when none). cmd_id is filled whenever the payload has two bytes.
 * A payload longer than the type's is accepted: the extra bytes are fields of a newer
 * version (the extension rule). */
int tt_decode_command(uint8_t type, const uint8_t *payload, size_t len, tt_command *cmd,
                      uint8_t *field);

/* ------------------------------------------------------------------ answers (board -> PC) */

typedef struct {
    uint16_t cmd_id, session;
    uint8_t protocol_version, fw_major, fw_minor, fw_patch;
    uint16_t tick_hz, counts_per_rev;
    uint32_t command_mask;
    uint8_t max_payload_bytes;
    uint16_t rx_buffer_bytes;
    uint8_t reply_queue_frames;
    uint16_t telemetry_min_decimation, heartbeat_ms, watchdog_ms, rx_silence_ms;
    uint32_t baud;
    uint8_t queue_blocks, stream_points; /* appended: programs and streams */
    uint16_t stream_period_min_ms, stream_period_max_ms;
} tt_hello_reply;

typedef struct {
    uint32_t tick;
    int32_t sp_pos, sp_vel, pos, vel; /* 1e-4 deg, 1e-4 deg/s */
    int16_t current_ma, duty;         /* mA, 1e-4 */
    uint8_t state, fault;
    uint32_t fault_flags;
    uint16_t bus_mv; /* appended: the measured bus voltage in mV, 0 = not measured */
} tt_telemetry;

typedef struct { uint16_t cmd_id; uint8_t msg_type; } tt_ack;
typedef struct {
    uint16_t cmd_id;
    uint8_t msg_type, code, field;
    uint32_t limit; /* f32 bits */
} tt_nack;
typedef struct {
    uint32_t tick;
    uint8_t fault;
    uint32_t value, fault_flags, threshold; /* value, threshold: f32 bits */
} tt_fault_report;
typedef struct { uint16_t cmd_id; uint8_t loop; uint32_t kp, ki, kd; } tt_gains;
typedef struct {
    uint16_t cmd_id;
    uint32_t v_max, a_max, current_limit, following_error, over_current_trip, travel_min,
        travel_max, over_speed, over_current_max; /* f32 bits */
    uint32_t bus_over_voltage, bus_under_voltage; /* appended: f32 bits, 0 = off */
    uint32_t thermal_trip, winding_estimate; /* appended: f32 bits, 0 = off */
    uint32_t thermal_derate;                  /* appended: f32 bits, 0 = off */
    uint32_t brake_current_limit;             /* appended: f32 bits, 0 = none */
} tt_limits;
typedef struct {
    uint16_t cmd_id;
    uint32_t tick;
    uint8_t state, fault;
    int32_t pos, vel, target;
    uint32_t fault_flags;
    uint16_t session;
    uint32_t sense_offset;     /* appended: f32 bits, A (the positive half-bridge's IS pin) */
    uint32_t sense_offset_neg; /* appended: f32 bits, A (the negative half-bridge's IS pin) */
} tt_status;
typedef struct {
    uint32_t tick;
    uint16_t session;
    uint8_t state;
    uint32_t fault_flags, rx_frames, rx_crc_errors, rx_header_errors, rx_bytes_dropped,
        rx_seq_gaps, rx_overflow_bytes, rx_silence_discards, rx_nacked, tx_telemetry_dropped;
    uint8_t queue_free, stream_free, stream_state; /* appended: flow control */
    uint32_t stream_underruns;
    uint16_t bus_mv; /* appended: the measured bus voltage in mV, 0 = unknown */
} tt_board_heartbeat;
typedef struct {
    uint16_t cmd_id;
    uint8_t bit, latched;
    uint32_t tick, value, threshold; /* value, threshold: f32 bits */
} tt_fault_info;
typedef struct {
    uint16_t cmd_id;
    uint8_t state, free_slots, queued;
    uint32_t done, override_pct; /* override_pct: f32 bits */
} tt_queue_status;
typedef struct {
    uint16_t cmd_id;
    uint8_t state, free_slots;
    uint32_t next_index, underruns;
    int32_t start_pos; /* 1e-4 deg */
} tt_stream_status;

/* Each writes the payload into `out` (TT_MAX_PAYLOAD bytes) and returns its length. */
size_t tt_encode_hello_reply(uint8_t *out, const tt_hello_reply *m);
size_t tt_encode_telemetry(uint8_t *out, const tt_telemetry *m);
size_t tt_encode_ack(uint8_t *out, const tt_ack *m);
size_t tt_encode_nack(uint8_t *out, const tt_nack *m);
size_t tt_encode_fault_report(uint8_t *out, const tt_fault_report *m);
size_t tt_encode_gains(uint8_t *out, const tt_gains *m);
size_t tt_encode_limits(uint8_t *out, const tt_limits *m);
size_t tt_encode_status(uint8_t *out, const tt_status *m);
size_t tt_encode_board_heartbeat(uint8_t *out, const tt_board_heartbeat *m);
size_t tt_encode_stream_status(uint8_t *out, const tt_stream_status *m);
size_t tt_encode_fault_info(uint8_t *out, const tt_fault_info *m);
size_t tt_encode_queue_status(uint8_t *out, const tt_queue_status *m);

#endif /* TT_LINK_H */
