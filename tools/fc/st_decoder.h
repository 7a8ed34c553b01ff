/* st_decoder.h: star tracker serial protocol, framing layer (C99, no allocation).
 *
 * Streaming decoder: feed bytes in any chunking; it calls back once per
 * intact packet (ASM, plausible CCSDS header, good CRC-16/CCITT-FALSE) and
 * counts what it dropped. Same algorithm as docs/protocol.md section 3.1.
 * Message payloads are parsed with st_protocol.h.
 */
#ifndef ST_DECODER_H
#define ST_DECODER_H

#include <stddef.h>
#include <stdint.h>

#include "st_protocol.h"

#define ST_CHUNK 256u
#define ST_BUF_SIZE (ST_MAX_PAYLOAD_TM + ST_OVERHEAD + ST_CHUNK)

typedef struct {
    unsigned apid;          /* message id */
    unsigned seq;           /* 14-bit sequence count */
    const uint8_t *payload; /* valid during the callback only */
    size_t len;             /* payload bytes */
} st_packet_t;

typedef void (*st_packet_cb)(const st_packet_t *packet, void *user);

typedef struct {
    unsigned long packets;       /* intact packets delivered */
    unsigned long bad_header;    /* ASM followed by an implausible header */
    unsigned long bad_crc;       /* plausible header, CRC wrong */
    unsigned long bytes_dropped; /* bytes not in a delivered packet */
} st_counters_t;

typedef struct {
    uint8_t buf[ST_BUF_SIZE];
    size_t len;
    unsigned type;       /* packet type accepted: 0 telemetry (FC side), 1 telecommand */
    size_t max_payload;
    st_counters_t counters;
} st_decoder_t;

/* CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, xorout 0. */
uint16_t st_crc16(const uint8_t *p, size_t n);

/* type: 0 to receive telemetry (the FC), 1 to receive telecommands. */
void st_decoder_init(st_decoder_t *d, unsigned type);

void st_decoder_feed(st_decoder_t *d, const uint8_t *data, size_t n, st_packet_cb cb,
                     void *user);

/* Build a packet (ASM, header, payload, CRC) into out (cap bytes). Returns its length,
 * or 0 if it does not fit. */
size_t st_build_packet(uint8_t *out, size_t cap, unsigned apid, unsigned type, unsigned seq,
                      const uint8_t *payload, size_t n);

#endif /* ST_DECODER_H */
