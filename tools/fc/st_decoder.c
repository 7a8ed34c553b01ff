/* st_decoder.c: framing layer of the star tracker serial protocol (C99). */
#include "st_decoder.h"

#include <string.h>

static const uint8_t ASM[4] = {0x1A, 0xCF, 0xFC, 0x1D};

uint16_t st_crc16(const uint8_t *p, size_t n)
{
    uint16_t crc = 0xFFFFu;
    size_t i;
    int b;
    for (i = 0; i < n; i++) {
        crc ^= (uint16_t)(p[i] << 8);
        for (b = 0; b < 8; b++)
            crc = (crc & 0x8000u) ? (uint16_t)((crc << 1) ^ 0x1021u) : (uint16_t)(crc << 1);
    }
    return crc;
}

void st_decoder_init(st_decoder_t *d, unsigned type)
{
    memset(d, 0, sizeof *d);
    d->type = type & 1u;
    d->max_payload = d->type ? ST_MAX_PAYLOAD_TC : ST_MAX_PAYLOAD_TM;
}

static size_t find_asm(const uint8_t *p, size_t len, size_t from)
{
    size_t i;
    for (i = from; i + 4 <= len; i++)
        if (p[i] == ASM[0] && memcmp(p + i, ASM, 4) == 0)
            return i;
    return (size_t)-1;
}

/* Consume what the buffer holds; keep an unfinished packet or partial ASM. */
static void scan(st_decoder_t *d, st_packet_cb cb, void *user)
{
    size_t pos = 0;
    for (;;) {
        size_t i = find_asm(d->buf, d->len, pos), end;
        unsigned w0, w1, w2;
        long n;
        if (i == (size_t)-1) {
            size_t keep = d->len >= 3 ? d->len - 3 : 0;
            if (keep < pos)
                keep = pos;
            d->counters.bytes_dropped += keep - pos;
            pos = keep;
            break;
        }
        d->counters.bytes_dropped += i - pos;
        pos = i;
        if (d->len - i < 10)
            break;
        w0 = st_get_u16(d->buf + i + 4);
        w1 = st_get_u16(d->buf + i + 6);
        w2 = st_get_u16(d->buf + i + 8);
        n = (long)w2 - 1;
        if ((w0 >> 13) != 0 || ((w0 >> 12) & 1u) != d->type || ((w0 >> 11) & 1u) != 0 ||
            (w1 >> 14) != 3u || n < 0 || (size_t)n > d->max_payload) {
            d->counters.bad_header++;
            d->counters.bytes_dropped++;
            pos = i + 1;
            continue;
        }
        end = i + ST_OVERHEAD + (size_t)n;
        if (d->len < end)
            break;
        if (st_crc16(d->buf + i + 4, 6 + (size_t)n) != st_get_u16(d->buf + end - 2)) {
            d->counters.bad_crc++;
            d->counters.bytes_dropped++;
            pos = i + 1;
            continue;
        }
        {
            st_packet_t f;
            f.apid = w0 & 0x7FFu;
            f.seq = w1 & 0x3FFFu;
            f.payload = d->buf + i + 10;
            f.len = (size_t)n;
            d->counters.packets++;
            cb(&f, user);
        }
        pos = end;
    }
    memmove(d->buf, d->buf + pos, d->len - pos);
    d->len -= pos;
}

void st_decoder_feed(st_decoder_t *d, const uint8_t *data, size_t n, st_packet_cb cb,
                     void *user)
{
    while (n > 0) {
        size_t take = sizeof d->buf - d->len;
        if (take > n)
            take = n;
        memcpy(d->buf + d->len, data, take);
        d->len += take;
        data += take;
        n -= take;
        scan(d, cb, user);
    }
}

size_t st_build_packet(uint8_t *out, size_t cap, unsigned apid, unsigned type, unsigned seq,
                      const uint8_t *payload, size_t n)
{
    if (n + ST_OVERHEAD > cap || n > 0xFFFDu)
        return 0;
    memcpy(out, ASM, 4);
    st_put_u16(out + 4, (uint16_t)(((type & 1u) << 12) | (apid & 0x7FFu)));
    st_put_u16(out + 6, (uint16_t)(0xC000u | (seq & 0x3FFFu)));
    st_put_u16(out + 8, (uint16_t)(n + 1));
    if (n)
        memcpy(out + 10, payload, n);
    st_put_u16(out + 10 + n, st_crc16(out + 4, 6 + n));
    return n + ST_OVERHEAD;
}
