/*
 * harness.c: a host-side command-line driver of tt_link for the tests (not for the board).
 * One command per line on stdin, answers on stdout:
 *
 *   F <hex>                 feed bytes; per good frame prints
 *                             frame <type> <seq> <payload hex>
 *                             cmd <code> <field> <cmd_id> <session> <fields...>
 *   R                       reset: a new decoder
 *   S                       the silence rule: give up the held partial frame
 *   T <0|1>                 one servo tick (1: bytes arrived in it)
 *   C                       counters: stats <frames> <header_errors> <crc_errors> <resyncs>
 *                             <bytes_dropped> <seq_gaps> <frames_missed>
 *                             <partial_discards> <held bytes>
 *   K <hex>                 the checks of these bytes: crc <CRC-8/SMBUS> <CRC-32/ISO-HDLC>
 *   E <type> <seq> <hex>    frame a payload: prints the frame in hex
 *   M <type> <seq> <v...>   encode a board -> PC message from its fields in wire order
 *                           (integers; f32 fields as their bit patterns): prints the frame
 *
 * Numbers are decimal; hex is lower- or upper-case pairs without separators ("-" = empty).
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "tt_link.h"

#define LINE_MAX_CHARS 65536

static int hex_value(int c)
{
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

static size_t parse_hex(const char *s, uint8_t *out, size_t cap)
{
    size_t n = 0;
    if (!s || strcmp(s, "-") == 0) return 0;
    while (s[0] && s[1] && n < cap) {
        int hi = hex_value((unsigned char)s[0]), lo = hex_value((unsigned char)s[1]);
        if (hi < 0 || lo < 0) break;
        out[n++] = (uint8_t)(hi * 16 + lo);
        s += 2;
    }
    return n;
}

static void print_hex(const uint8_t *p, size_t n)
{
    if (!n) fputs("-", stdout);
    while (n--) printf("%02x", *p++);
}

static void on_frame(void *ctx, uint8_t type, uint8_t seq, const uint8_t *payload, uint8_t len)
{
    tt_command c;
    uint8_t field;
    int code = tt_decode_command(type, payload, len, &c, &field);
    (void)ctx;
    printf("frame %u %u ", type, seq);
    print_hex(payload, len);
    printf("\ncmd %d %u %u %u", code, field, c.cmd_id, c.session);
    if (code == TT_OK || code == TT_OUT_OF_RANGE) {
        switch (type) {
        case TT_HELLO: printf(" %u %u", c.u.hello.version_min, c.u.hello.version_max); break;
        case TT_MOVE:
            printf(" %ld %lu %lu %lu %u", (long)c.u.move.target, (unsigned long)c.u.move.v_max,
                   (unsigned long)c.u.move.a_max, (unsigned long)c.u.move.j_max,
                   c.u.move.profile);
            break;
        case TT_STOP: printf(" %lu", (unsigned long)c.u.stop.a_max); break;
        case TT_SET_ENABLE: printf(" %u", c.u.set_enable.enable); break;
        case TT_SET_GAINS:
            printf(" %u %lu %lu %lu", c.u.set_gains.loop, (unsigned long)c.u.set_gains.kp,
                   (unsigned long)c.u.set_gains.ki, (unsigned long)c.u.set_gains.kd);
            break;
        case TT_GET_GAINS: printf(" %u", c.u.get_gains.loop); break;
        case TT_SET_LIMITS:
            printf(" %lu %lu %lu %lu %lu", (unsigned long)c.u.set_limits.v_max,
                   (unsigned long)c.u.set_limits.a_max,
                   (unsigned long)c.u.set_limits.current_limit,
                   (unsigned long)c.u.set_limits.following_error,
                   (unsigned long)c.u.set_limits.over_current_trip);
            printf(" %lu %lu %lu %lu", (unsigned long)c.u.set_limits.bus_over_voltage,
                   (unsigned long)c.u.set_limits.bus_under_voltage,
                   (unsigned long)c.u.set_limits.thermal_derate,
                   (unsigned long)c.u.set_limits.thermal_trip);
            printf(" %lu", (unsigned long)c.u.set_limits.brake_current_limit);
            break;
        case TT_SET_TELEMETRY: printf(" %u", c.u.set_telemetry.decimation); break;
        case TT_GET_FAULT: printf(" %u", c.u.get_fault.bit); break;
        case TT_QUEUE_SEGMENT:
            printf(" %ld %lu %lu", (long)c.u.queue_segment.target,
                   (unsigned long)c.u.queue_segment.v_max,
                   (unsigned long)c.u.queue_segment.dwell);
            break;
        case TT_QUEUE_CONTROL:
            printf(" %u %lu", c.u.queue_control.action,
                   (unsigned long)c.u.queue_control.override_pct);
            break;
        case TT_STREAM_CONTROL:
            printf(" %u %u %lu %u", c.u.stream_control.action, c.u.stream_control.interp,
                   (unsigned long)c.u.stream_control.period, c.u.stream_control.prefill);
            break;
        case TT_STREAM_POINTS: {
            int k;
            printf(" %lu %u", (unsigned long)c.u.stream_points.first_index,
                   c.u.stream_points.count);
            for (k = 0; k < 5; k++) printf(" %ld", (long)c.u.stream_points.pos[k]);
            for (k = 0; k < 5; k++) printf(" %lu", (unsigned long)c.u.stream_points.vel[k]);
            break;
        }
        case TT_JOG:
            printf(" %lu %lu %u", (unsigned long)c.u.jog.vel, (unsigned long)c.u.jog.a_max,
                   c.u.jog.timeout_ms);
            break;
        default: break;
        }
    }
    printf("\n");
}

static uint32_t v(char **tok, int *ok)
{
    char *s = strtok(NULL, " \t\r\n"), *end;
    long long x;
    (void)tok;
    if (!s) {
        *ok = 0;
        return 0;
    }
    x = strtoll(s, &end, 10);
    return (uint32_t)x;
}

static size_t encode_message(unsigned type, uint8_t *p, int *ok)
{
    char **t = NULL;
    switch (type) {
    case TT_HELLO_REPLY: {
        tt_hello_reply m;
        m.cmd_id = (uint16_t)v(t, ok); m.session = (uint16_t)v(t, ok);
        m.protocol_version = (uint8_t)v(t, ok); m.fw_major = (uint8_t)v(t, ok);
        m.fw_minor = (uint8_t)v(t, ok); m.fw_patch = (uint8_t)v(t, ok);
        m.tick_hz = (uint16_t)v(t, ok); m.counts_per_rev = (uint16_t)v(t, ok);
        m.command_mask = v(t, ok); m.max_payload_bytes = (uint8_t)v(t, ok);
        m.rx_buffer_bytes = (uint16_t)v(t, ok); m.reply_queue_frames = (uint8_t)v(t, ok);
        m.telemetry_min_decimation = (uint16_t)v(t, ok); m.heartbeat_ms = (uint16_t)v(t, ok);
        m.watchdog_ms = (uint16_t)v(t, ok); m.rx_silence_ms = (uint16_t)v(t, ok);
        m.baud = v(t, ok);
        m.queue_blocks = (uint8_t)v(t, ok); m.stream_points = (uint8_t)v(t, ok);
        m.stream_period_min_ms = (uint16_t)v(t, ok);
        m.stream_period_max_ms = (uint16_t)v(t, ok);
        return tt_encode_hello_reply(p, &m);
    }
    case TT_TELEMETRY: {
        tt_telemetry m;
        m.tick = v(t, ok); m.sp_pos = (int32_t)v(t, ok); m.sp_vel = (int32_t)v(t, ok);
        m.pos = (int32_t)v(t, ok); m.vel = (int32_t)v(t, ok);
        m.current_ma = (int16_t)v(t, ok); m.duty = (int16_t)v(t, ok);
        m.state = (uint8_t)v(t, ok); m.fault = (uint8_t)v(t, ok); m.fault_flags = v(t, ok);
        m.bus_mv = (uint16_t)v(t, ok);
        return tt_encode_telemetry(p, &m);
    }
    case TT_ACK: {
        tt_ack m;
        m.cmd_id = (uint16_t)v(t, ok); m.msg_type = (uint8_t)v(t, ok);
        return tt_encode_ack(p, &m);
    }
    case TT_NACK: {
        tt_nack m;
        m.cmd_id = (uint16_t)v(t, ok); m.msg_type = (uint8_t)v(t, ok);
        m.code = (uint8_t)v(t, ok); m.field = (uint8_t)v(t, ok); m.limit = v(t, ok);
        return tt_encode_nack(p, &m);
    }
    case TT_FAULT_REPORT: {
        tt_fault_report m;
        m.tick = v(t, ok); m.fault = (uint8_t)v(t, ok); m.value = v(t, ok);
        m.fault_flags = v(t, ok); m.threshold = v(t, ok);
        return tt_encode_fault_report(p, &m);
    }
    case TT_GAINS: {
        tt_gains m;
        m.cmd_id = (uint16_t)v(t, ok); m.loop = (uint8_t)v(t, ok);
        m.kp = v(t, ok); m.ki = v(t, ok); m.kd = v(t, ok);
        return tt_encode_gains(p, &m);
    }
    case TT_LIMITS: {
        tt_limits m;
        m.cmd_id = (uint16_t)v(t, ok); m.v_max = v(t, ok); m.a_max = v(t, ok);
        m.current_limit = v(t, ok); m.following_error = v(t, ok);
        m.over_current_trip = v(t, ok); m.travel_min = v(t, ok); m.travel_max = v(t, ok);
        m.over_speed = v(t, ok); m.over_current_max = v(t, ok);
        m.bus_over_voltage = v(t, ok); m.bus_under_voltage = v(t, ok);
        m.thermal_trip = v(t, ok); m.winding_estimate = v(t, ok);
        m.thermal_derate = v(t, ok);
        m.brake_current_limit = v(t, ok);
        return tt_encode_limits(p, &m);
    }
    case TT_STATUS: {
        tt_status m;
        m.cmd_id = (uint16_t)v(t, ok); m.tick = v(t, ok); m.state = (uint8_t)v(t, ok);
        m.fault = (uint8_t)v(t, ok); m.pos = (int32_t)v(t, ok); m.vel = (int32_t)v(t, ok);
        m.target = (int32_t)v(t, ok); m.fault_flags = v(t, ok);
        m.session = (uint16_t)v(t, ok); m.sense_offset = v(t, ok);
        m.sense_offset_neg = v(t, ok);
        return tt_encode_status(p, &m);
    }
    case TT_BOARD_HEARTBEAT: {
        tt_board_heartbeat m;
        m.tick = v(t, ok); m.session = (uint16_t)v(t, ok); m.state = (uint8_t)v(t, ok);
        m.fault_flags = v(t, ok); m.rx_frames = v(t, ok); m.rx_crc_errors = v(t, ok);
        m.rx_header_errors = v(t, ok); m.rx_bytes_dropped = v(t, ok);
        m.rx_seq_gaps = v(t, ok); m.rx_overflow_bytes = v(t, ok);
        m.rx_silence_discards = v(t, ok); m.rx_nacked = v(t, ok);
        m.tx_telemetry_dropped = v(t, ok);
        m.queue_free = (uint8_t)v(t, ok); m.stream_free = (uint8_t)v(t, ok);
        m.stream_state = (uint8_t)v(t, ok); m.stream_underruns = v(t, ok);
        m.bus_mv = (uint16_t)v(t, ok);
        return tt_encode_board_heartbeat(p, &m);
    }
    case TT_FAULT_INFO: {
        tt_fault_info m;
        m.cmd_id = (uint16_t)v(t, ok); m.bit = (uint8_t)v(t, ok);
        m.latched = (uint8_t)v(t, ok); m.tick = v(t, ok); m.value = v(t, ok);
        m.threshold = v(t, ok);
        return tt_encode_fault_info(p, &m);
    }
    case TT_QUEUE_STATUS: {
        tt_queue_status m;
        m.cmd_id = (uint16_t)v(t, ok); m.state = (uint8_t)v(t, ok);
        m.free_slots = (uint8_t)v(t, ok); m.queued = (uint8_t)v(t, ok);
        m.done = v(t, ok); m.override_pct = v(t, ok);
        return tt_encode_queue_status(p, &m);
    }
    case TT_STREAM_STATUS: {
        tt_stream_status m;
        m.cmd_id = (uint16_t)v(t, ok); m.state = (uint8_t)v(t, ok);
        m.free_slots = (uint8_t)v(t, ok); m.next_index = v(t, ok);
        m.underruns = v(t, ok); m.start_pos = (int32_t)v(t, ok);
        return tt_encode_stream_status(p, &m);
    }
    default:
        *ok = 0;
        return 0;
    }
}

int main(void)
{
    static char line[LINE_MAX_CHARS];
    static uint8_t data[LINE_MAX_CHARS / 2];
    uint8_t frame[TT_MAX_FRAME], payload[TT_MAX_PAYLOAD];
    tt_decoder d;
    tt_decoder_init(&d);
    while (fgets(line, sizeof line, stdin)) {
        char *op = strtok(line, " \t\r\n");
        if (!op) continue;
        if (strcmp(op, "R") == 0) {
            tt_decoder_init(&d);
        } else if (strcmp(op, "F") == 0) {
            size_t n = parse_hex(strtok(NULL, " \t\r\n"), data, sizeof data);
            tt_decoder_feed(&d, data, n, on_frame, NULL);
        } else if (strcmp(op, "S") == 0) {
            tt_decoder_silence(&d, on_frame, NULL);
        } else if (strcmp(op, "T") == 0) {
            const char *s = strtok(NULL, " \t\r\n");
            tt_decoder_tick(&d, s && s[0] == '1', on_frame, NULL);
        } else if (strcmp(op, "C") == 0) {
            const tt_rx_stats *s = &d.stats;
            printf("stats %lu %lu %lu %lu %lu %lu %lu %lu %u\n", (unsigned long)s->frames,
                   (unsigned long)s->header_errors, (unsigned long)s->crc_errors,
                   (unsigned long)s->resyncs, (unsigned long)s->bytes_dropped,
                   (unsigned long)s->seq_gaps, (unsigned long)s->frames_missed,
                   (unsigned long)s->partial_discards, d.n);
        } else if (strcmp(op, "K") == 0) {
            size_t n = parse_hex(strtok(NULL, " \t\r\n"), data, sizeof data);
            printf("crc %u %lu\n", tt_crc8(data, n), (unsigned long)tt_crc32(data, n));
        } else if (strcmp(op, "E") == 0) {
            unsigned type = (unsigned)atoi(strtok(NULL, " \t\r\n"));
            unsigned seq = (unsigned)atoi(strtok(NULL, " \t\r\n"));
            size_t n = parse_hex(strtok(NULL, " \t\r\n"), data, sizeof data);
            size_t k = tt_frame_encode(frame, (uint8_t)type, (uint8_t)seq, data, n);
            if (!k) printf("error payload of %lu bytes\n", (unsigned long)n);
            else {
                print_hex(frame, k);
                printf("\n");
            }
        } else if (strcmp(op, "M") == 0) {
            int ok = 1;
            unsigned type = (unsigned)atoi(strtok(NULL, " \t\r\n"));
            unsigned seq = (unsigned)atoi(strtok(NULL, " \t\r\n"));
            size_t n = encode_message(type, payload, &ok);
            if (!ok) printf("error type %u or its fields\n", type);
            else {
                size_t k = tt_frame_encode(frame, (uint8_t)type, (uint8_t)seq, payload, n);
                print_hex(frame, k);
                printf("\n");
            }
        } else {
            printf("error unknown command %s\n", op);
        }
        fflush(stdout);
    }
    return 0;
}
