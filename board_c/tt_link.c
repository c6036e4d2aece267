/*
 * tt_link.c: the board side of the turntable PC link, protocol version 2.
 * See tt_link.h; the specification is docs/protocol.md (sections 2, 3 and 4).
 */
#include "tt_link.h"

#include <string.h>

/* crc8_table[i]: 8 rounds of (c << 1) ^ (c & 0x80 ? 0x07 : 0) from c = i (CRC-8/SMBUS).
 * crc32_table[i]: 8 rounds of (c >> 1) ^ (c & 1 ? 0xEDB88320 : 0) (CRC-32/ISO-HDLC). */
static const uint8_t crc8_table[256] = {
    0x00, 0x07, 0x0E, 0x09, 0x1C, 0x1B, 0x12, 0x15, 0x38, 0x3F, 0x36, 0x31,
    0x24, 0x23, 0x2A, 0x2D, 0x70, 0x77, 0x7E, 0x79, 0x6C, 0x6B, 0x62, 0x65,
    0x48, 0x4F, 0x46, 0x41, 0x54, 0x53, 0x5A, 0x5D, 0xE0, 0xE7, 0xEE, 0xE9,
    0xFC, 0xFB, 0xF2, 0xF5, 0xD8, 0xDF, 0xD6, 0xD1, 0xC4, 0xC3, 0xCA, 0xCD,
    0x90, 0x97, 0x9E, 0x99, 0x8C, 0x8B, 0x82, 0x85, 0xA8, 0xAF, 0xA6, 0xA1,
    0xB4, 0xB3, 0xBA, 0xBD, 0xC7, 0xC0, 0xC9, 0xCE, 0xDB, 0xDC, 0xD5, 0xD2,
    0xFF, 0xF8, 0xF1, 0xF6, 0xE3, 0xE4, 0xED, 0xEA, 0xB7, 0xB0, 0xB9, 0xBE,
    0xAB, 0xAC, 0xA5, 0xA2, 0x8F, 0x88, 0x81, 0x86, 0x93, 0x94, 0x9D, 0x9A,
    0x27, 0x20, 0x29, 0x2E, 0x3B, 0x3C, 0x35, 0x32, 0x1F, 0x18, 0x11, 0x16,
    0x03, 0x04, 0x0D, 0x0A, 0x57, 0x50, 0x59, 0x5E, 0x4B, 0x4C, 0x45, 0x42,
    0x6F, 0x68, 0x61, 0x66, 0x73, 0x74, 0x7D, 0x7A, 0x89, 0x8E, 0x87, 0x80,
    0x95, 0x92, 0x9B, 0x9C, 0xB1, 0xB6, 0xBF, 0xB8, 0xAD, 0xAA, 0xA3, 0xA4,
    0xF9, 0xFE, 0xF7, 0xF0, 0xE5, 0xE2, 0xEB, 0xEC, 0xC1, 0xC6, 0xCF, 0xC8,
    0xDD, 0xDA, 0xD3, 0xD4, 0x69, 0x6E, 0x67, 0x60, 0x75, 0x72, 0x7B, 0x7C,
    0x51, 0x56, 0x5F, 0x58, 0x4D, 0x4A, 0x43, 0x44, 0x19, 0x1E, 0x17, 0x10,
    0x05, 0x02, 0x0B, 0x0C, 0x21, 0x26, 0x2F, 0x28, 0x3D, 0x3A, 0x33, 0x34,
    0x4E, 0x49, 0x40, 0x47, 0x52, 0x55, 0x5C, 0x5B, 0x76, 0x71, 0x78, 0x7F,
    0x6A, 0x6D, 0x64, 0x63, 0x3E, 0x39, 0x30, 0x37, 0x22, 0x25, 0x2C, 0x2B,
    0x06, 0x01, 0x08, 0x0F, 0x1A, 0x1D, 0x14, 0x13, 0xAE, 0xA9, 0xA0, 0xA7,
    0xB2, 0xB5, 0xBC, 0xBB, 0x96, 0x91, 0x98, 0x9F, 0x8A, 0x8D, 0x84, 0x83,
    0xDE, 0xD9, 0xD0, 0xD7, 0xC2, 0xC5, 0xCC, 0xCB, 0xE6, 0xE1, 0xE8, 0xEF,
    0xFA, 0xFD, 0xF4, 0xF3,
};

static const uint32_t crc32_table[256] = {
    0x00000000u, 0x77073096u, 0xEE0E612Cu, 0x990951BAu, 0x076DC419u, 0x706AF48Fu,
    0xE963A535u, 0x9E6495A3u, 0x0EDB8832u, 0x79DCB8A4u, 0xE0D5E91Eu, 0x97D2D988u,
    0x09B64C2Bu, 0x7EB17CBDu, 0xE7B82D07u, 0x90BF1D91u, 0x1DB71064u, 0x6AB020F2u,
    0xF3B97148u, 0x84BE41DEu, 0x1ADAD47Du, 0x6DDDE4EBu, 0xF4D4B551u, 0x83D385C7u,
    0x136C9856u, 0x646BA8C0u, 0xFD62F97Au, 0x8A65C9ECu, 0x14015C4Fu, 0x63066CD9u,
    0xFA0F3D63u, 0x8D080DF5u, 0x3B6E20C8u, 0x4C69105Eu, 0xD56041E4u, 0xA2677172u,
    0x3C03E4D1u, 0x4B04D447u, 0xD20D85FDu, 0xA50AB56Bu, 0x35B5A8FAu, 0x42B2986Cu,
    0xDBBBC9D6u, 0xACBCF940u, 0x32D86CE3u, 0x45DF5C75u, 0xDCD60DCFu, 0xABD13D59u,
    0x26D930ACu, 0x51DE003Au, 0xC8D75180u, 0xBFD06116u, 0x21B4F4B5u, 0x56B3C423u,
    0xCFBA9599u, 0xB8BDA50Fu, 0x2802B89Eu, 0x5F058808u, 0xC60CD9B2u, 0xB10BE924u,
    0x2F6F7C87u, 0x58684C11u, 0xC1611DABu, 0xB6662D3Du, 0x76DC4190u, 0x01DB7106u,
    0x98D220BCu, 0xEFD5102Au, 0x71B18589u, 0x06B6B51Fu, 0x9FBFE4A5u, 0xE8B8D433u,
    0x7807C9A2u, 0x0F00F934u, 0x9609A88Eu, 0xE10E9818u, 0x7F6A0DBBu, 0x086D3D2Du,
    0x91646C97u, 0xE6635C01u, 0x6B6B51F4u, 0x1C6C6162u, 0x856530D8u, 0xF262004Eu,
    0x6C0695EDu, 0x1B01A57Bu, 0x8208F4C1u, 0xF50FC457u, 0x65B0D9C6u, 0x12B7E950u,
    0x8BBEB8EAu, 0xFCB9887Cu, 0x62DD1DDFu, 0x15DA2D49u, 0x8CD37CF3u, 0xFBD44C65u,
    0x4DB26158u, 0x3AB551CEu, 0xA3BC0074u, 0xD4BB30E2u, 0x4ADFA541u, 0x3DD895D7u,
    0xA4D1C46Du, 0xD3D6F4FBu, 0x4369E96Au, 0x346ED9FCu, 0xAD678846u, 0xDA60B8D0u,
    0x44042D73u, 0x33031DE5u, 0xAA0A4C5Fu, 0xDD0D7CC9u, 0x5005713Cu, 0x270241AAu,
    0xBE0B1010u, 0xC90C2086u, 0x5768B525u, 0x206F85B3u, 0xB966D409u, 0xCE61E49Fu,
    0x5EDEF90Eu, 0x29D9C998u, 0xB0D09822u, 0xC7D7A8B4u, 0x59B33D17u, 0x2EB40D81u,
    0xB7BD5C3Bu, 0xC0BA6CADu, 0xEDB88320u, 0x9ABFB3B6u, 0x03B6E20Cu, 0x74B1D29Au,
    0xEAD54739u, 0x9DD277AFu, 0x04DB2615u, 0x73DC1683u, 0xE3630B12u, 0x94643B84u,
    0x0D6D6A3Eu, 0x7A6A5AA8u, 0xE40ECF0Bu, 0x9309FF9Du, 0x0A00AE27u, 0x7D079EB1u,
    0xF00F9344u, 0x8708A3D2u, 0x1E01F268u, 0x6906C2FEu, 0xF762575Du, 0x806567CBu,
    0x196C3671u, 0x6E6B06E7u, 0xFED41B76u, 0x89D32BE0u, 0x10DA7A5Au, 0x67DD4ACCu,
    0xF9B9DF6Fu, 0x8EBEEFF9u, 0x17B7BE43u, 0x60B08ED5u, 0xD6D6A3E8u, 0xA1D1937Eu,
    0x38D8C2C4u, 0x4FDFF252u, 0xD1BB67F1u, 0xA6BC5767u, 0x3FB506DDu, 0x48B2364Bu,
    0xD80D2BDAu, 0xAF0A1B4Cu, 0x36034AF6u, 0x41047A60u, 0xDF60EFC3u, 0xA867DF55u,
    0x316E8EEFu, 0x4669BE79u, 0xCB61B38Cu, 0xBC66831Au, 0x256FD2A0u, 0x5268E236u,
    0xCC0C7795u, 0xBB0B4703u, 0x220216B9u, 0x5505262Fu, 0xC5BA3BBEu, 0xB2BD0B28u,
    0x2BB45A92u, 0x5CB36A04u, 0xC2D7FFA7u, 0xB5D0CF31u, 0x2CD99E8Bu, 0x5BDEAE1Du,
    0x9B64C2B0u, 0xEC63F226u, 0x756AA39Cu, 0x026D930Au, 0x9C0906A9u, 0xEB0E363Fu,
    0x72076785u, 0x05005713u, 0x95BF4A82u, 0xE2B87A14u, 0x7BB12BAEu, 0x0CB61B38u,
    0x92D28E9Bu, 0xE5D5BE0Du, 0x7CDCEFB7u, 0x0BDBDF21u, 0x86D3D2D4u, 0xF1D4E242u,
    0x68DDB3F8u, 0x1FDA836Eu, 0x81BE16CDu, 0xF6B9265Bu, 0x6FB077E1u, 0x18B74777u,
    0x88085AE6u, 0xFF0F6A70u, 0x66063BCAu, 0x11010B5Cu, 0x8F659EFFu, 0xF862AE69u,
    0x616BFFD3u, 0x166CCF45u, 0xA00AE278u, 0xD70DD2EEu, 0x4E048354u, 0x3903B3C2u,
    0xA7672661u, 0xD06016F7u, 0x4969474Du, 0x3E6E77DBu, 0xAED16A4Au, 0xD9D65ADCu,
    0x40DF0B66u, 0x37D83BF0u, 0xA9BCAE53u, 0xDEBB9EC5u, 0x47B2CF7Fu, 0x30B5FFE9u,
    0xBDBDF21Cu, 0xCABAC28Au, 0x53B39330u, 0x24B4A3A6u, 0xBAD03605u, 0xCDD70693u,
    0x54DE5729u, 0x23D967BFu, 0xB3667A2Eu, 0xC4614AB8u, 0x5D681B02u, 0x2A6F2B94u,
    0xB40BBE37u, 0xC30C8EA1u, 0x5A05DF1Bu, 0x2D02EF8Du,
};

uint8_t tt_crc8(const uint8_t *p, size_t n)
{
    uint8_t crc = 0x00u;
    while (n--) crc = crc8_table[crc ^ *p++];
    return crc;
}

uint32_t tt_crc32(const uint8_t *p, size_t n)
{
    uint32_t crc = 0xFFFFFFFFu;
    while (n--) crc = (crc >> 8) ^ crc32_table[(crc ^ *p++) & 0xFFu];
    return crc ^ 0xFFFFFFFFu;
}

int tt_f32_finite(uint32_t bits) { return ((bits >> 23) & 0xFFu) != 0xFFu; }

/* ------------------------------------------------------------------ little-endian fields */

static void put_u8(uint8_t *p, size_t *at, uint8_t v) { p[(*at)++] = v; }
static void put_u16(uint8_t *p, size_t *at, uint16_t v)
{
    p[(*at)++] = (uint8_t)v;
    p[(*at)++] = (uint8_t)(v >> 8);
}
static void put_u32(uint8_t *p, size_t *at, uint32_t v)
{
    put_u16(p, at, (uint16_t)v);
    put_u16(p, at, (uint16_t)(v >> 16));
}
static uint16_t get_u16(const uint8_t *p) { return (uint16_t)(p[0] | (p[1] << 8)); }
static uint32_t get_u32(const uint8_t *p)
{
    return (uint32_t)p[0] | ((uint32_t)p[1] << 8) | ((uint32_t)p[2] << 16) |
           ((uint32_t)p[3] << 24);
}

size_t tt_frame_encode(uint8_t *out, uint8_t type, uint8_t seq, const uint8_t *payload,
                       size_t len)
{
    uint32_t crc;
    size_t end;
    if (len > TT_MAX_PAYLOAD) return 0;
    out[0] = TT_SYNC0;
    out[1] = TT_SYNC1;
    out[2] = (uint8_t)len;
    out[3] = type;
    out[4] = seq;
    out[5] = tt_crc8(out + 2, 3);
    if (len) memcpy(out + TT_HEADER_BYTES, payload, len);
    end = TT_HEADER_BYTES + len;
    crc = tt_crc32(out + 2, end - 2);
    put_u32(out, &end, crc);
    return end;
}

/* ------------------------------------------------------------------ receiving */

void tt_decoder_init(tt_decoder *d) { memset(d, 0, sizeof *d); }

static void drop_front(tt_decoder *d, size_t k)
{
    memmove(d->buf, d->buf + k, d->n - k);
    d->n = (uint8_t)(d->n - k);
}

static void dropped(tt_decoder *d, size_t k)
{
    d->stats.bytes_dropped += (uint32_t)k;
    d->hunting = 1;
}

/* Decode from the start of buf until it holds only the start of a frame (docs section 3:
 * hunt, header, body, back up one byte after a failed sync, never skip a claimed length). */
static void scan(tt_decoder *d, tt_frame_fn fn, void *ctx)
{
    for (;;) {
        size_t n = d->n, j = 0, len, end;
        uint8_t *b = d->buf;
        while (j + 1 < n && !(b[j] == TT_SYNC0 && b[j + 1] == TT_SYNC1)) j++;
        if (j + 1 >= n) {
            /* no sync pair: keep a trailing 0xA5, its 0x5A may come next */
            size_t keep_from = (n && b[n - 1] == TT_SYNC0) ? n - 1 : n;
            if (keep_from) {
                dropped(d, keep_from);
                drop_front(d, keep_from);
            }
            return;
        }
        if (j) {
            dropped(d, j);
            drop_front(d, j);
            n = d->n;
        }
        if (n < TT_HEADER_BYTES) return;
        len = b[2];
        if (len > TT_MAX_PAYLOAD || tt_crc8(b + 2, 3) != b[5]) {
            d->stats.header_errors++;
            dropped(d, 1);
            drop_front(d, 1);
            continue;
        }
        end = TT_OVERHEAD_BYTES + len;
        if (n < end) return;
        if (tt_crc32(b + 2, end - 2 - TT_CRC_BYTES) != get_u32(b + end - TT_CRC_BYTES)) {
            d->stats.crc_errors++;
            dropped(d, 1);
            drop_front(d, 1);
            continue;
        }
        d->stats.frames++;
        if (d->hunting) {
            d->stats.resyncs++;
            d->hunting = 0;
        }
        if (d->have_seq && b[4] != (uint8_t)(d->last_seq + 1u)) {
            d->stats.seq_gaps++;
            d->stats.frames_missed += (uint8_t)(b[4] - d->last_seq - 1u);
        }
        d->have_seq = 1;
        d->last_seq = b[4];
        if (fn) fn(ctx, b[3], b[4], b + TT_HEADER_BYTES, (uint8_t)len);
        drop_front(d, end);
    }
}

void tt_decoder_feed(tt_decoder *d, const uint8_t *data, size_t n, tt_frame_fn fn, void *ctx)
{
    /* Byte by byte: after each scan the buffer holds at most a partial frame (73 bytes). */
    while (n--) {
        d->buf[d->n++] = *data++;
        if (d->n >= 2 || d->buf[0] != TT_SYNC0) scan(d, fn, ctx);
    }
    d->idle_ticks = 0;
}

void tt_decoder_silence(tt_decoder *d, tt_frame_fn fn, void *ctx)
{
    if (d->n) d->stats.partial_discards++;
    while (d->n) {
        /* the head of buf is an incomplete candidate (or a lone 0xA5): drop one byte */
        dropped(d, 1);
        drop_front(d, 1);
        scan(d, fn, ctx);
    }
    d->idle_ticks = 0;
}

void tt_decoder_tick(tt_decoder *d, int bytes_this_tick, tt_frame_fn fn, void *ctx)
{
    if (bytes_this_tick) {
        d->idle_ticks = 0;
        return;
    }
    if (d->idle_ticks < 0xFFFFu) d->idle_ticks++;
    if (d->n && d->idle_ticks >= TT_RX_SILENCE_TICKS) tt_decoder_silence(d, fn, ctx);
}

/* ------------------------------------------------------------------ commands */

/* Payload length of each command type (index = type), 0 = not a command: the version 2.0
 * fields, then with the fields appended since (section 6; only SetLimits has some, each a
 * 4-byte f32). A payload between the two ends after an appended field or is BAD_LENGTH. */
static const uint8_t command_len[0x13] = {
    0, 6, 4, 21, 8, 5, 4, 17, 5, 24, 4, 4, 6, 5, 16, 9, 11, 49, 14,
};
static const uint8_t command_full_len[0x13] = {
    0, 6, 4, 21, 8, 5, 4, 17, 5, 44, 4, 4, 6, 5, 16, 9, 11, 49, 14,
};

int tt_decode_command(uint8_t type, const uint8_t *p, size_t len, tt_command *cmd,
                      uint8_t *field)
{
    uint8_t padded[TT_MAX_PAYLOAD];
    memset(cmd, 0, sizeof *cmd);
    cmd->type = type;
    *field = TT_NO_FIELD;
    if (len >= 2) cmd->cmd_id = get_u16(p);
    if (type >= 0x80u) return TT_NOT_A_COMMAND;
    if (type >= sizeof command_len || command_len[type] == 0) return TT_UNKNOWN_TYPE;
    if (len < command_len[type]) return TT_BAD_LENGTH;
    if (len < command_full_len[type]) {
        /* An older PC's payload: the appended fields it lacks read as 0. */
        if ((len - command_len[type]) % 4u != 0u) return TT_BAD_LENGTH;
        memcpy(padded, p, len);
        memset(padded + len, 0, command_full_len[type] - len);
        p = padded;
    }
    cmd->session = get_u16(p + 2);
    switch (type) {
    case TT_HELLO:
        cmd->u.hello.version_min = p[4];
        cmd->u.hello.version_max = p[5];
        break;
    case TT_MOVE:
        cmd->u.move.target = (int32_t)get_u32(p + 4);
        cmd->u.move.v_max = get_u32(p + 8);
        cmd->u.move.a_max = get_u32(p + 12);
        cmd->u.move.j_max = get_u32(p + 16);
        cmd->u.move.profile = p[20];
        if (p[20] > 2u) {
            *field = 6;
            return TT_OUT_OF_RANGE;
        }
        break;
    case TT_STOP:
        cmd->u.stop.a_max = get_u32(p + 4);
        break;
    case TT_SET_ENABLE:
        cmd->u.set_enable.enable = p[4];
        if (p[4] > 1u) {
            *field = 2;
            return TT_OUT_OF_RANGE;
        }
        break;
    case TT_SET_GAINS:
        cmd->u.set_gains.loop = p[4];
        cmd->u.set_gains.kp = get_u32(p + 5);
        cmd->u.set_gains.ki = get_u32(p + 9);
        cmd->u.set_gains.kd = get_u32(p + 13);
        if (p[4] > 2u) {
            *field = 2;
            return TT_OUT_OF_RANGE;
        }
        break;
    case TT_GET_GAINS:
        cmd->u.get_gains.loop = p[4];
        if (p[4] > 2u) {
            *field = 2;
            return TT_OUT_OF_RANGE;
        }
        break;
    case TT_SET_LIMITS:
        cmd->u.set_limits.v_max = get_u32(p + 4);
        cmd->u.set_limits.a_max = get_u32(p + 8);
        cmd->u.set_limits.current_limit = get_u32(p + 12);
        cmd->u.set_limits.following_error = get_u32(p + 16);
        cmd->u.set_limits.over_current_trip = get_u32(p + 20);
        cmd->u.set_limits.bus_over_voltage = get_u32(p + 24);
        cmd->u.set_limits.bus_under_voltage = get_u32(p + 28);
        cmd->u.set_limits.thermal_derate = get_u32(p + 32);
        cmd->u.set_limits.thermal_trip = get_u32(p + 36);
        cmd->u.set_limits.brake_current_limit = get_u32(p + 40);
        break;
    case TT_SET_TELEMETRY:
        cmd->u.set_telemetry.decimation = get_u16(p + 4);
        break;
    case TT_GET_FAULT:
        cmd->u.get_fault.bit = p[4];
        break;
    case TT_QUEUE_SEGMENT:
        cmd->u.queue_segment.target = (int32_t)get_u32(p + 4);
        cmd->u.queue_segment.v_max = get_u32(p + 8);
        cmd->u.queue_segment.dwell = get_u32(p + 12);
        break;
    case TT_QUEUE_CONTROL:
        cmd->u.queue_control.action = p[4];
        cmd->u.queue_control.override_pct = get_u32(p + 5);
        if (p[4] > 4u) {
            *field = 2;
            return TT_OUT_OF_RANGE;
        }
        break;
    case TT_STREAM_CONTROL:
        cmd->u.stream_control.action = p[4];
        cmd->u.stream_control.interp = p[5];
        cmd->u.stream_control.period = get_u32(p + 6);
        cmd->u.stream_control.prefill = p[10];
        if (p[4] > 3u) {
            *field = 2;
            return TT_OUT_OF_RANGE;
        }
        if (p[5] > 1u) {
            *field = 3;
            return TT_OUT_OF_RANGE;
        }
        break;
    case TT_STREAM_POINTS: {
        int k;
        cmd->u.stream_points.first_index = get_u32(p + 4);
        cmd->u.stream_points.count = p[8];
        for (k = 0; k < 5; k++) {
            cmd->u.stream_points.pos[k] = (int32_t)get_u32(p + 9 + 4 * k);
            cmd->u.stream_points.vel[k] = get_u32(p + 29 + 4 * k);
        }
        break;
    }
    case TT_JOG:
        cmd->u.jog.vel = get_u32(p + 4);
        cmd->u.jog.a_max = get_u32(p + 8);
        cmd->u.jog.timeout_ms = get_u16(p + 12);
        break;
    default: /* Heartbeat, ClearFault, GetLimits, GetStatus: cmd_id and session only */
        break;
    }
    return TT_OK;
}

/* ------------------------------------------------------------------ answers */

size_t tt_encode_hello_reply(uint8_t *out, const tt_hello_reply *m)
{
    size_t at = 0;
    put_u16(out, &at, m->cmd_id);
    put_u16(out, &at, m->session);
    put_u8(out, &at, m->protocol_version);
    put_u8(out, &at, m->fw_major);
    put_u8(out, &at, m->fw_minor);
    put_u8(out, &at, m->fw_patch);
    put_u16(out, &at, m->tick_hz);
    put_u16(out, &at, m->counts_per_rev);
    put_u32(out, &at, m->command_mask);
    put_u8(out, &at, m->max_payload_bytes);
    put_u16(out, &at, m->rx_buffer_bytes);
    put_u8(out, &at, m->reply_queue_frames);
    put_u16(out, &at, m->telemetry_min_decimation);
    put_u16(out, &at, m->heartbeat_ms);
    put_u16(out, &at, m->watchdog_ms);
    put_u16(out, &at, m->rx_silence_ms);
    put_u32(out, &at, m->baud);
    put_u8(out, &at, m->queue_blocks);
    put_u8(out, &at, m->stream_points);
    put_u16(out, &at, m->stream_period_min_ms);
    put_u16(out, &at, m->stream_period_max_ms);
    return at;
}

size_t tt_encode_telemetry(uint8_t *out, const tt_telemetry *m)
{
    size_t at = 0;
    put_u32(out, &at, m->tick);
    put_u32(out, &at, (uint32_t)m->sp_pos);
    put_u32(out, &at, (uint32_t)m->sp_vel);
    put_u32(out, &at, (uint32_t)m->pos);
    put_u32(out, &at, (uint32_t)m->vel);
    put_u16(out, &at, (uint16_t)m->current_ma);
    put_u16(out, &at, (uint16_t)m->duty);
    put_u8(out, &at, m->state);
    put_u8(out, &at, m->fault);
    put_u32(out, &at, m->fault_flags);
    put_u16(out, &at, m->bus_mv);
    return at;
}

size_t tt_encode_ack(uint8_t *out, const tt_ack *m)
{
    size_t at = 0;
    put_u16(out, &at, m->cmd_id);
    put_u8(out, &at, m->msg_type);
    return at;
}

size_t tt_encode_nack(uint8_t *out, const tt_nack *m)
{
    size_t at = 0;
    put_u16(out, &at, m->cmd_id);
    put_u8(out, &at, m->msg_type);
    put_u8(out, &at, m->code);
    put_u8(out, &at, m->field);
    put_u32(out, &at, m->limit);
    return at;
}

size_t tt_encode_fault_report(uint8_t *out, const tt_fault_report *m)
{
    size_t at = 0;
    put_u32(out, &at, m->tick);
    put_u8(out, &at, m->fault);
    put_u32(out, &at, m->value);
    put_u32(out, &at, m->fault_flags);
    put_u32(out, &at, m->threshold);
    return at;
}

size_t tt_encode_gains(uint8_t *out, const tt_gains *m)
{
    size_t at = 0;
    put_u16(out, &at, m->cmd_id);
    put_u8(out, &at, m->loop);
    put_u32(out, &at, m->kp);
    put_u32(out, &at, m->ki);
    put_u32(out, &at, m->kd);
    return at;
}

size_t tt_encode_limits(uint8_t *out, const tt_limits *m)
{
    size_t at = 0;
    put_u16(out, &at, m->cmd_id);
    put_u32(out, &at, m->v_max);
    put_u32(out, &at, m->a_max);
    put_u32(out, &at, m->current_limit);
    put_u32(out, &at, m->following_error);
    put_u32(out, &at, m->over_current_trip);
    put_u32(out, &at, m->travel_min);
    put_u32(out, &at, m->travel_max);
    put_u32(out, &at, m->over_speed);
    put_u32(out, &at, m->over_current_max);
    put_u32(out, &at, m->bus_over_voltage);
    put_u32(out, &at, m->bus_under_voltage);
    put_u32(out, &at, m->thermal_trip);
    put_u32(out, &at, m->winding_estimate);
    put_u32(out, &at, m->thermal_derate);
    put_u32(out, &at, m->brake_current_limit);
    return at;
}

size_t tt_encode_status(uint8_t *out, const tt_status *m)
{
    size_t at = 0;
    put_u16(out, &at, m->cmd_id);
    put_u32(out, &at, m->tick);
    put_u8(out, &at, m->state);
    put_u8(out, &at, m->fault);
    put_u32(out, &at, (uint32_t)m->pos);
    put_u32(out, &at, (uint32_t)m->vel);
    put_u32(out, &at, (uint32_t)m->target);
    put_u32(out, &at, m->fault_flags);
    put_u16(out, &at, m->session);
    put_u32(out, &at, m->sense_offset);
    put_u32(out, &at, m->sense_offset_neg);
    return at;
}

size_t tt_encode_board_heartbeat(uint8_t *out, const tt_board_heartbeat *m)
{
    size_t at = 0;
    put_u32(out, &at, m->tick);
    put_u16(out, &at, m->session);
    put_u8(out, &at, m->state);
    put_u32(out, &at, m->fault_flags);
    put_u32(out, &at, m->rx_frames);
    put_u32(out, &at, m->rx_crc_errors);
    put_u32(out, &at, m->rx_header_errors);
    put_u32(out, &at, m->rx_bytes_dropped);
    put_u32(out, &at, m->rx_seq_gaps);
    put_u32(out, &at, m->rx_overflow_bytes);
    put_u32(out, &at, m->rx_silence_discards);
    put_u32(out, &at, m->rx_nacked);
    put_u32(out, &at, m->tx_telemetry_dropped);
    put_u8(out, &at, m->queue_free);
    put_u8(out, &at, m->stream_free);
    put_u8(out, &at, m->stream_state);
    put_u32(out, &at, m->stream_underruns);
    put_u16(out, &at, m->bus_mv);
    return at;
}

size_t tt_encode_fault_info(uint8_t *out, const tt_fault_info *m)
{
    size_t at = 0;
    put_u16(out, &at, m->cmd_id);
    put_u8(out, &at, m->bit);
    put_u8(out, &at, m->latched);
    put_u32(out, &at, m->tick);
    put_u32(out, &at, m->value);
    put_u32(out, &at, m->threshold);
    return at;
}

size_t tt_encode_queue_status(uint8_t *out, const tt_queue_status *m)
{
    size_t at = 0;
    put_u16(out, &at, m->cmd_id);
    put_u8(out, &at, m->state);
    put_u8(out, &at, m->free_slots);
    put_u8(out, &at, m->queued);
    put_u32(out, &at, m->done);
    put_u32(out, &at, m->override_pct);
    return at;
}

size_t tt_encode_stream_status(uint8_t *out, const tt_stream_status *m)
{
    size_t at = 0;
    put_u16(out, &at, m->cmd_id);
    put_u8(out, &at, m->state);
    put_u8(out, &at, m->free_slots);
    put_u32(out, &at, m->next_index);
    put_u32(out, &at, m->underruns);
    put_u32(out, &at, (uint32_t)m->start_pos);
    return at;
}
