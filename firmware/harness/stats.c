/* The harness's figures as one JSON line ("stats" command, the end of a --seconds run): per
 * board the interrupts' cycles, instructions and steps, the firmware's own counters (fw_stats);
 * the UART's reply period; the I2C transactions; the real-time pacing's lag. */
#include <stdio.h>

#include "harness.h"

void print_stats(double wall_s)
{
    double us = 1e6 / F_CPU_HZ;
    printf("stats {\"sim_s\": %.6f, \"wall_s\": %.6f, \"lag_max_ms\": %.3f,"
           " \"behind_s\": %.6f, \"lag_drops\": %llu, \"lag_dropped_s\": %.6f, \"boards\": [",
           (double)H.now / F_CPU_HZ, wall_s, H.lag_max_s * 1e3, H.behind_s,
           (unsigned long long)H.lag_drops, H.lag_dropped_s);
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
                   " \"i2c_errors\": %u, \"bad_writes\": %u, \"commands\": %u}",
                   (unsigned long)(d[0] | d[1] << 8 | (uint32_t)d[2] << 16 | (uint32_t)d[3] << 24),
                   d[4] | d[5] << 8, d[6] | d[7] << 8, d[8] | d[9] << 8, d[10] | d[11] << 8,
                   d[12] | d[13] << 8);
        }
        printf("}");
    }
    printf("], \"uart\": {\"rx_bytes\": %llu, \"rx_lost_power\": %llu,"
           " \"tx_bytes\": %llu, \"tx_lost\": %llu, \"replies\": %llu, \"period_us_min\": %.1f,"
           " \"period_us_mean\": %.1f, \"period_us_max\": %.1f},",
           (unsigned long long)H.rx_bytes,
           (unsigned long long)H.rx_lost_power, (unsigned long long)H.tx_bytes,
           (unsigned long long)H.tx_lost,
           (unsigned long long)H.replies, H.period_min * us,
           H.period_n ? (double)H.period_sum / H.period_n * us : 0.0, H.period_max * us);
    printf(" \"i2c\": {\"transactions\": %llu, \"naks\": %llu, \"us_min\": %.1f,"
           " \"us_mean\": %.1f, \"us_max\": %.1f}}\n",
           (unsigned long long)H.i2c_transactions, (unsigned long long)H.i2c_naks,
           H.i2c_min * us, H.i2c_transactions ? (double)H.i2c_sum / H.i2c_transactions * us : 0.0,
           H.i2c_max * us);
    fflush(stdout);
}

