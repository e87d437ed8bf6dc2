/* Joint 1's UART seen from the harness: host bytes in at 115 200 baud, reply frames out (to the
 * pty, the reply log and the period figures), the --script schedule; and the figures' JSON. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

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
    if (H.pty_fd >= 0 && write(H.pty_fd, &c, 1) < 0) {
        /* nobody reading and the pty buffer full: the byte is lost, as on an unread line */
    }
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

void print_stats(double wall_s)
{
    double us = 1e6 / F_CPU_HZ;
    printf("stats {\"sim_s\": %.6f, \"wall_s\": %.6f, \"lag_drops\": %llu, \"boards\": [",
           (double)H.now / F_CPU_HZ, wall_s, (unsigned long long)H.lag_drops);
    for (int i = 0; i < N_BOARDS; i++) {
        board_t *b = &H.boards[i];
        isr_stat_t *s = &b->isr[H.isr_vector];
        printf("%s{\"joint\": %d, \"powered\": %d, \"isr_count\": %llu, \"isr_worst_cycles\": %llu,"
               " \"isr_mean_cycles\": %.1f, \"motor_steps\": %lld, \"steps\": %llu,"
               " \"blocked\": %llu, \"pc\": %u, \"instructions\": %llu, \"vectors\": {",
               i ? ", " : "", i + 1, b->powered,
               (unsigned long long)s->count, (unsigned long long)s->worst,
               s->count ? (double)s->total / s->count : 0.0, (long long)b->joint.motor_steps,
               (unsigned long long)b->joint.steps, (unsigned long long)b->joint.blocked,
               (unsigned)b->avr->pc, (unsigned long long)b->instructions);
        const char *sep = "";
        for (int v = 1; v < 26; v++) {
            if (b->isr[v].count) {
                printf("%s\"%d\": [%llu, %llu]", sep, v, (unsigned long long)b->isr[v].count,
                       (unsigned long long)b->isr[v].worst);
                sep = ", ";
            }
        }
        printf("}");
        if (b->stats_addr) {
            const uint8_t *d = b->avr->data + b->stats_addr;
            printf(", \"fw\": {\"loops\": %lu, \"rx_overflows\": %u, \"bad_frames\": %u,"
                   " \"i2c_errors\": %u, \"bad_writes\": %u}",
                   (unsigned long)(d[0] | d[1] << 8 | (uint32_t)d[2] << 16 | (uint32_t)d[3] << 24),
                   d[4] | d[5] << 8, d[6] | d[7] << 8, d[8] | d[9] << 8, d[10] | d[11] << 8);
        }
        printf("}");
    }
    printf("], \"uart\": {\"rx_bytes\": %llu, \"rx_lost_power\": %llu,"
           " \"tx_bytes\": %llu, \"replies\": %llu, \"period_us_min\": %.1f,"
           " \"period_us_mean\": %.1f, \"period_us_max\": %.1f},",
           (unsigned long long)H.rx_bytes,
           (unsigned long long)H.rx_lost_power, (unsigned long long)H.tx_bytes,
           (unsigned long long)H.replies, H.period_min * us,
           H.period_n ? (double)H.period_sum / H.period_n * us : 0.0, H.period_max * us);
    printf(" \"i2c\": {\"transactions\": %llu, \"naks\": %llu, \"us_min\": %.1f,"
           " \"us_mean\": %.1f, \"us_max\": %.1f}}\n",
           (unsigned long long)H.i2c_transactions, (unsigned long long)H.i2c_naks,
           H.i2c_min * us, H.i2c_transactions ? (double)H.i2c_sum / H.i2c_transactions * us : 0.0,
           H.i2c_max * us);
    fflush(stdout);
}

