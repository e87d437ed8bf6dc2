/* The host-driven mode (--lockstep): the harness has no clock of its own and runs only as far as
 * its host says, so the host's clock can be the boards' clock (armbench's virtual-time loop,
 * fakes/avr_vt.py) and runs as fast as the boards can be simulated.
 *
 * One command a line on stdin; answers on stdout, one line each:
 *
 *   "run CYCLE"   run the four boards until the global cycle reaches CYCLE (rounded up to a
 *                 quantum) or until joint 1's UART has sent the end of a reply frame ('#'),
 *                 whichever comes first; answers "at CYCLE S1 S2 S3 S4 BYTES": the cycle reached,
 *                 the four motors' positions (microsteps, the joint model's truth), and the UART
 *                 bytes sent since the last answer in hex ("-" when none). Stopping at a frame's
 *                 end lets the host see each reply at the time its '#' left, and answer it then.
 *   "send HEX"    bytes for joint 1's UART (two hex digits each), queued at the current cycle and
 *                 fed at 115 200 baud as the pty's are; no answer.
 *   the commands of control.c ("power off", "power on", "eeprom blank", "home", "stats",
 *                 "quit"), applied at the current cycle; only "stats" answers.
 *
 * The end of stdin quits. The host never runs the boards backwards: a CYCLE at or before the
 * current one answers at once with the current cycle. */
#define _GNU_SOURCE
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "harness.h"

/* UART bytes not yet answered (a reply frame is ~30 bytes; the run stops before this fills) */
static uint8_t out_buf[1024];
static size_t out_len;
static int serving, frame_end;

/* Keep a byte joint 1's UART sent for the next answer; 0 when not serving in lockstep (the
 * byte is the pty's then). */
int lockstep_put(uint8_t c)
{
    if (!serving) {
        return 0;
    }
    if (out_len < sizeof out_buf) {
        out_buf[out_len++] = c;
    } else {
        H.tx_lost++;
    }
    if (c == '#') {
        frame_end = 1;
    }
    return 1;
}

static void answer_run(uint64_t target)
{
    frame_end = 0;
    while (H.now < target && !frame_end && out_len + 64 < sizeof out_buf) {
        harness_step();
    }
    printf("at %llu", (unsigned long long)H.now);
    for (int i = 0; i < N_BOARDS; i++) {
        printf(" %lld", (long long)H.boards[i].joint.motor_steps);
    }
    putchar(' ');
    if (out_len == 0) {
        putchar('-');
    }
    for (size_t i = 0; i < out_len; i++) {
        printf("%02x", out_buf[i]);
    }
    putchar('\n');
    fflush(stdout);
    out_len = 0;
}

static int hex_value(int c)
{
    return c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10
        : c >= 'A' && c <= 'F' ? c - 'A' + 10 : -1;
}

static void queue_hex(const char *hex)
{
    uint8_t bytes[256];
    size_t n = 0;
    for (; hex[0] && hex[1]; hex += 2) {
        int hi = hex_value(hex[0]), lo = hex_value(hex[1]);
        if (hi < 0 || lo < 0) {
            fprintf(stderr, "armfw-harness: send: not hex: %s\n", hex);
            return;
        }
        bytes[n++] = (uint8_t)(hi << 4 | lo);
        if (n == sizeof bytes) {
            uart_queue(bytes, n);
            n = 0;
        }
    }
    uart_queue(bytes, n);
}

static double wall_s(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

/* Serve the host until "quit" or the end of stdin. */
void lockstep_serve(void)
{
    serving = 1;
    double wall0 = wall_s();
    char *line = NULL;
    size_t cap = 0;
    ssize_t n;
    while ((n = getline(&line, &cap, stdin)) > 0) {
        line[strcspn(line, "\r\n")] = 0;
        if (strncmp(line, "run ", 4) == 0) {
            answer_run(strtoull(line + 4, NULL, 10));
        } else if (strncmp(line, "send ", 5) == 0) {
            queue_hex(line + 5);
        } else if (!harness_command(line, wall_s() - wall0)) {
            break;
        }
    }
    free(line);
    serving = 0;
}
