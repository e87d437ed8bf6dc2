/* Joint 1's UART seen from the harness: host bytes in at 115 200 baud, reply frames out (to the
 * pty, the reply log and the period figures), the --script schedule. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <simavr/avr_uart.h>

#include "harness.h"

/* --script FILE, one event a line at a simulated time:
 *   "<seconds> <text>"        the text's bytes (no white space) on joint 1's UART;
 *   "<seconds> @hex <hex>"    any bytes, two hex digits each;
 *   "<seconds> @power off|on" a power cut or its end, all four boards (as the "power" commands).
 * --reply-log FILE: "<seconds> <reply>" for each reply frame (the time its '#' was written). */
typedef struct script_event_t {
    uint64_t at;
    int power;        /* -1: bytes; 0: power off; 1: power on */
    uint8_t *bytes;
    size_t n;
} script_event_t;
static script_event_t *script;
static size_t script_len, script_next;
FILE *reply_log;
static char reply_buf[64];
static unsigned reply_len;

static int hex_digit(int c)
{
    return c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10
        : c >= 'A' && c <= 'F' ? c - 'A' + 10 : -1;
}

static void script_line(const char *path, char *line)
{
    char *rest;
    double t = strtod(line, &rest);
    if (rest == line) {
        return;   /* blank or not an event */
    }
    rest += strspn(rest, " \t");
    rest[strcspn(rest, "\r\n")] = 0;
    script_event_t e = {(uint64_t)(t * F_CPU_HZ), -1, NULL, 0};
    if (strncmp(rest, "@power ", 7) == 0) {
        e.power = strcmp(rest + 7, "on") == 0;
        if (!e.power && strcmp(rest + 7, "off") != 0) {
            die("script: @power wants on or off", path);
        }
    } else if (strncmp(rest, "@hex ", 5) == 0) {
        const char *h = rest + 5;
        size_t len = strlen(h);
        e.bytes = malloc(len / 2 + 1);
        for (size_t i = 0; i + 1 < len + 1 && h[i] && h[i + 1]; i += 2) {
            int hi = hex_digit(h[i]), lo = hex_digit(h[i + 1]);
            if (hi < 0 || lo < 0) {
                die("script: @hex wants pairs of hex digits", path);
            }
            e.bytes[e.n++] = (uint8_t)(hi << 4 | lo);
        }
    } else {
        size_t len = strcspn(rest, " \t");
        e.bytes = malloc(len + 1);
        memcpy(e.bytes, rest, len);
        e.n = len;
    }
    script_event_t *grown = realloc(script, (script_len + 1) * sizeof *script);
    if (!grown) {
        die("script: out of memory", path);
    }
    script = grown;
    script[script_len++] = e;
}

void load_script(const char *path)
{
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "armfw-harness: cannot read script %s\n", path);
        exit(2);
    }
    char *line = NULL;
    size_t cap = 0;
    while (getline(&line, &cap, f) > 0) {
        script_line(path, line);
    }
    free(line);
    fclose(f);
}

void script_due(void)
{
    while (script_next < script_len && script[script_next].at <= H.now) {
        script_event_t *e = &script[script_next++];
        if (e->power >= 0) {
            power_all(e->power);
        } else {
            uart_queue(e->bytes, e->n);
        }
    }
}

/* Host bytes for joint 1's UART: queued behind those still to go on the line (dropped when the
 * queue is full, as a host's own buffer would). */
void uart_queue(const uint8_t *bytes, size_t n)
{
    for (size_t i = 0; i < n; i++) {
        unsigned next = (H.rx_head + 1) % sizeof H.rx_queue;
        if (next == H.rx_tail) {
            return;
        }
        if (H.rx_head == H.rx_tail) {
            H.rx_queued_at = H.now;   /* nothing waiting: this byte starts now, or when the
                                         byte on the line has gone */
        }
        H.rx_queue[H.rx_head] = bytes[i];
        H.rx_head = next;
    }
}

void uart_out(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    (void)param;
    uint8_t c = (uint8_t)value;
    H.tx_bytes++;
    if (c == '$') {
        uint64_t t = H.boards[0].avr->cycle;
        if (H.last_reply_at) {
            uint64_t p = t - H.last_reply_at;
            H.period_sum += p;
            H.period_n++;
            if (p > H.period_max) {
                H.period_max = p;
            }
            if (H.period_min == 0 || p < H.period_min) {
                H.period_min = p;
            }
        }
        H.last_reply_at = t;
    } else if (c == '#') {
        H.replies++;
    }
    if (reply_log) {
        if (c == '$') {
            reply_len = 0;
        }
        if (reply_len < sizeof reply_buf - 1) {
            reply_buf[reply_len++] = (char)c;
        }
        if (c == '#') {
            reply_buf[reply_len] = 0;
            fprintf(reply_log, "%.7f %s\n", (double)H.boards[0].avr->cycle / F_CPU_HZ, reply_buf);
        }
    }
    if (!lockstep_put(c)) {
        pty_put(c);
    }
}

/* Host bytes on joint 1's UART at 115 200 baud, back to back while the host has more. A byte is
 * handed to simavr's UART as its start bit begins, and simavr raises RXC one byte time later (the
 * chip's byte time, board.c), when its stop bit is in; a byte that begins while the master is
 * unpowered or still in reset is lost. */
void uart_in(void)
{
    board_t *m = &H.boards[0];
    if (H.rx_head == H.rx_tail) {
        return;
    }
    uint64_t start = H.rx_next_at > H.rx_queued_at ? H.rx_next_at : H.rx_queued_at;
    if (H.now < start) {
        return;
    }
    uint8_t c = H.rx_queue[H.rx_tail];
    H.rx_tail = (H.rx_tail + 1) % sizeof H.rx_queue;
    H.rx_next_at = start + F_CPU_HZ * 10ull / 115200ull;   /* one byte at 115200 8N1 */
    if (!m->powered || H.now < m->boot_at) {
        H.rx_lost_power++;   /* before Serial.begin(): lost */
        return;
    }
    H.rx_bytes++;
    avr_raise_irq(avr_io_getirq(m->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT), c);
}
