/* st_command: send one command to the star tracker and wait for its ACK or NACK.
 *
 *   cc -std=c99 -Wall -Wextra -pedantic -O2 -o st_command st_command.c st_decoder.c
 *   st_command /dev/ttyAMA0 921600 ping
 *   st_command /dev/ttyAMA0 921600 set-mode 2
 *   st_command /dev/ttyAMA0 921600 time-sync
 *   st_command /dev/ttyAMA0 921600 set-velocity -7.5 0.25 1.0
 *
 * What an FC does for every command (docs/protocol.md section 8): give it a
 * new sequence count, send it, match the reply by (cmd_id, cmd_seq) among the
 * telemetry that keeps arriving, and send it again with a new count when no
 * reply came within 200 ms (3 tries).
 *
 * time-sync and set-velocity stamp TAI from this computer's CLOCK_REALTIME
 * (UTC) plus ST_TAI_MINUS_UTC_S, right before the write: a real FC takes TAI
 * from its GNSS receiver or its own time system (section 6.1).
 *
 * Prints one line: `ACK NAME seq S` or `NACK NAME seq S code C`.
 * Exit status: 0 ACK, 1 NACK, 2 no reply, 3 bad arguments or port.
 */
#define _POSIX_C_SOURCE 200809L

#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "st_decoder.h"

/* TAI - UTC since 2017-01-01 (IERS Bulletin C); update at the next leap second. */
#define ST_TAI_MINUS_UTC_S 37
#define REPLY_TIMEOUT_MS 200
#define TRIES 3

typedef struct {
    unsigned cmd_id, cmd_seq; /* the command waited for */
    int answered;             /* 0 none yet, 1 ACK, -1 NACK */
    unsigned code;            /* the reply's reason code */
} waiting_t;

static void on_packet(const st_packet_t *packet, void *user)
{
    waiting_t *w = (waiting_t *)user;
    st_ack_t reply; /* ACK and NACK share one layout */
    if (packet->apid != ST_ID_ACK && packet->apid != ST_ID_NACK)
        return; /* telemetry: ATTITUDE, CENTROIDS, STATUS */
    if (st_parse_ack(packet->payload, packet->len, &reply) != ST_OK)
        return;
    if (reply.cmd_id != w->cmd_id || reply.cmd_seq != w->cmd_seq)
        return; /* the reply to another command */
    w->answered = packet->apid == ST_ID_ACK ? 1 : -1;
    w->code = reply.code;
}

static int open_port(const char *device, long baud)
{
    struct termios tio;
    speed_t speed;
    int fd;
    switch (baud) {
    case 9600: speed = B9600; break;
    case 19200: speed = B19200; break;
    case 38400: speed = B38400; break;
    case 57600: speed = B57600; break;
    case 115200: speed = B115200; break;
    case 230400: speed = B230400; break;
    case 460800: speed = B460800; break;
    case 921600: speed = B921600; break;
    default:
        fprintf(stderr, "st_command: unsupported baud rate %ld\n", baud);
        return -1;
    }
    fd = open(device, O_RDWR | O_NOCTTY);
    if (fd < 0 || tcgetattr(fd, &tio) != 0) {
        fprintf(stderr, "st_command: %s: %s\n", device, strerror(errno));
        if (fd >= 0)
            close(fd);
        return -1;
    }
    /* raw 8N1: no echo, no line editing, no character translation, no flow control */
    tio.c_iflag &= ~(tcflag_t)(IGNBRK | BRKINT | PARMRK | ISTRIP | INLCR | IGNCR | ICRNL |
                               IXON | IXOFF);
    tio.c_oflag &= ~(tcflag_t)OPOST;
    tio.c_lflag &= ~(tcflag_t)(ECHO | ECHONL | ICANON | ISIG | IEXTEN);
    tio.c_cflag &= ~(tcflag_t)(CSIZE | PARENB | CSTOPB);
    tio.c_cflag |= CS8 | CREAD | CLOCAL;
    tio.c_cc[VMIN] = 0;
    tio.c_cc[VTIME] = 0;
    if (cfsetispeed(&tio, speed) != 0 || cfsetospeed(&tio, speed) != 0 ||
        tcsetattr(fd, TCSANOW, &tio) != 0) {
        fprintf(stderr, "st_command: %s: %s\n", device, strerror(errno));
        close(fd);
        return -1;
    }
    return fd;
}

static uint64_t tai_now_ns(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_REALTIME, &ts);
    return ((uint64_t)ts.tv_sec + ST_TAI_MINUS_UTC_S) * 1000000000u + (uint64_t)ts.tv_nsec;
}

static long elapsed_ms(const struct timespec *since)
{
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return (long)(now.tv_sec - since->tv_sec) * 1000 + (now.tv_nsec - since->tv_nsec) / 1000000;
}

/* The payload of the command in argv (after the name); its id, or -1 if the words are wrong. */
static int build_payload(int argc, char **argv, uint8_t *payload, size_t *len)
{
    const char *name = argv[0];
    if (strcmp(name, "ping") == 0 && argc == 1) {
        st_ping_t m = {0};
        *len = st_pack_ping(payload, &m);
        return ST_ID_PING;
    }
    if (strcmp(name, "request-status") == 0 && argc == 1) {
        st_request_status_t m = {0};
        *len = st_pack_request_status(payload, &m);
        return ST_ID_REQUEST_STATUS;
    }
    if (strcmp(name, "set-mode") == 0 && argc == 2) {
        st_set_mode_t m;
        m.mode = (uint8_t)strtoul(argv[1], NULL, 10);
        *len = st_pack_set_mode(payload, &m);
        return ST_ID_SET_MODE;
    }
    if (strcmp(name, "time-sync") == 0 && argc == 1) {
        *len = ST_TIME_SYNC_SIZE; /* filled in right before each write */
        return ST_ID_TIME_SYNC;
    }
    if (strcmp(name, "set-velocity") == 0 && argc == 4) {
        st_set_velocity_t m;
        m.t_ns = tai_now_ns();
        m.vx_km_s = strtof(argv[1], NULL);
        m.vy_km_s = strtof(argv[2], NULL);
        m.vz_km_s = strtof(argv[3], NULL);
        *len = st_pack_set_velocity(payload, &m);
        return ST_ID_SET_VELOCITY;
    }
    return -1;
}

int main(int argc, char **argv)
{
    static st_decoder_t decoder;
    uint8_t payload[ST_MAX_PAYLOAD_TC], packet[ST_MAX_PAYLOAD_TC + ST_OVERHEAD], buf[512];
    size_t len = 0;
    unsigned seq = 0; /* a real FC keeps one count per command id across its lifetime */
    waiting_t w;
    int fd, id, attempt;
    if (argc < 4 || (id = build_payload(argc - 3, argv + 3, payload, &len)) < 0) {
        fprintf(stderr, "usage: st_command DEVICE BAUD ping | request-status | set-mode N | "
                        "time-sync | set-velocity VX VY VZ\n");
        return 3;
    }
    fd = open_port(argv[1], strtol(argv[2], NULL, 10));
    if (fd < 0)
        return 3;
    st_decoder_init(&decoder, 0); /* receive telemetry */
    for (attempt = 0; attempt < TRIES; attempt++, seq = (seq + 1) & 0x3FFFu) {
        struct timespec sent;
        size_t n;
        if (id == ST_ID_TIME_SYNC) { /* the FC's TAI as the first byte leaves */
            st_time_sync_t m;
            m.fc_time_ns = tai_now_ns();
            st_pack_time_sync(payload, &m);
        }
        n = st_build_packet(packet, sizeof packet, (unsigned)id, 1, seq, payload, len);
        if (write(fd, packet, n) != (ssize_t)n) {
            fprintf(stderr, "st_command: write: %s\n", strerror(errno));
            close(fd);
            return 3;
        }
        w.cmd_id = (unsigned)id;
        w.cmd_seq = seq;
        w.answered = 0;
        clock_gettime(CLOCK_MONOTONIC, &sent);
        while (!w.answered) {
            long left = REPLY_TIMEOUT_MS - elapsed_ms(&sent);
            struct pollfd p;
            ssize_t got;
            if (left <= 0)
                break;
            p.fd = fd;
            p.events = POLLIN;
            if (poll(&p, 1, (int)left) <= 0)
                continue;
            got = read(fd, buf, sizeof buf);
            if (got > 0)
                st_decoder_feed(&decoder, buf, (size_t)got, on_packet, &w);
        }
        if (w.answered) {
            close(fd);
            if (w.answered > 0) {
                printf("ACK %s seq %u\n", argv[3], seq);
                return 0;
            }
            printf("NACK %s seq %u code %u\n", argv[3], seq, w.code);
            return 1;
        }
    }
    close(fd);
    printf("no reply to %s after %d tries\n", argv[3], TRIES);
    return 2;
}
