/* st_dump: decode telemetry from stdin and print one line per packet.
 *
 *   cc -std=c99 -O2 -o st_dump st_dump.c st_decoder.c
 *   st_dump < capture.bin            (or: st_dump CHUNK to read CHUNK bytes at a time)
 *
 * Lines: `NAME seq=S field=value ...`; the last line gives the counters.
 */
#define ST_WANT_PRINT
#include <stdio.h>
#include <stdlib.h>

#include "st_decoder.h"

typedef struct {
    unsigned long unknown_id, wrong_length, out_of_range;
} rejects_t;

static void on_packet(const st_packet_t *f, void *user)
{
    rejects_t *r = (rejects_t *)user;
    int rc;
    printf("%u ", f->seq);
    rc = st_print_payload(stdout, f->apid, f->payload, f->len);
    if (rc == ST_UNKNOWN_ID)
        r->unknown_id++;
    else if (rc == ST_WRONG_LENGTH)
        r->wrong_length++;
    else if (rc == ST_OUT_OF_RANGE)
        r->out_of_range++;
    printf(rc == ST_OK ? "\n" : "REJECTED %d\n", rc);
}

int main(int argc, char **argv)
{
    static st_decoder_t d;
    uint8_t chunk[4096];
    size_t want = argc > 1 ? (size_t)strtoul(argv[1], NULL, 10) : sizeof chunk, got;
    rejects_t r = {0, 0, 0};
    if (want == 0 || want > sizeof chunk)
        want = sizeof chunk;
    st_decoder_init(&d, 0);
    while ((got = fread(chunk, 1, want, stdin)) > 0)
        st_decoder_feed(&d, chunk, got, on_packet, &r);
    printf("COUNTERS packets=%lu bad_header=%lu bad_crc=%lu unknown_id=%lu wrong_length=%lu "
           "out_of_range=%lu\n", d.counters.packets, d.counters.bad_header, d.counters.bad_crc,
           r.unknown_id, r.wrong_length, r.out_of_range);
    return 0;
}
