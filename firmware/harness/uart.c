/* Joint 1's UART seen from the harness: host bytes in at 115 200 baud, reply frames out (to the
 * pty, the reply log and the period figures), the --script schedule. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <simavr/avr_uart.h>

#include "harness.h"

/* --script FILE: "<seconds> <bytes>" lines, each put on joint 1's UART at that simulated time;
 * --reply-log FILE: "<seconds> <reply>" for each reply frame (the time its '#' was written). */
#define MAX_SCRIPT 256
static struct {
    uint64_t at;
    char text[128];
} script[MAX_SCRIPT];
static int script_len, script_next;
FILE *reply_log;
static char reply_buf[64];
static unsigned reply_len;

void load_script(const char *path)
{
    FILE *f = fopen(path, "r");
    if (!f) {
        fprintf(stderr, "armfw-harness: cannot read script %s\n", path);
        exit(2);
    }
    double t;
    char text[128];
    while (script_len < MAX_SCRIPT && fscanf(f, "%lf %127s", &t, text) == 2) {
        script[script_len].at = (uint64_t)(t * F_CPU_HZ);
        memcpy(script[script_len].text, text, sizeof text);
        script_len++;
    }
    fclose(f);
}

void script_due(void)
{
    while (script_next < script_len && script[script_next].at <= H.now) {
        for (const char *c = script[script_next].text; *c; c++) {
            H.rx_queue[H.rx_head] = (uint8_t)*c;
            H.rx_head = (H.rx_head + 1) % sizeof H.rx_queue;
        }
        script_next++;
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
    pty_put(c);
}

void uart_in(void)
{
    board_t *m = &H.boards[0];
    if (H.rx_head == H.rx_tail || H.now < H.rx_next_at) {
        return;
    }
    uint8_t c = H.rx_queue[H.rx_tail];
    H.rx_tail = (H.rx_tail + 1) % sizeof H.rx_queue;
    H.rx_next_at = H.now + F_CPU_HZ * 10ull / 115200ull;   /* one byte at 115200 8N1 */
    if (!m->powered || H.now < m->boot_at) {
        H.rx_lost_power++;   /* before Serial.begin(): lost */
        return;
    }
    H.rx_bytes++;
    avr_raise_irq(avr_io_getirq(m->avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT), c);
}
