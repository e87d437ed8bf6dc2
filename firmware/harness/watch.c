/* What the differential fuzzer needs to see of the firmware (docs/fuzzing.md):
 *
 *   --event-log FILE        "<seconds> cmd <n> <frame>" each time the master takes a valid
 *                           command (its fw_stats.commands counter moved; the frame rebuilt from
 *                           its cmd_ticks/cmd_duty, given by --command-vars), "<seconds> overflow
 *                           <n>" when its receive buffer dropped a byte, "<seconds> power on|off",
 *                           "<seconds> eeprom <joint> <address> <value>" when a board starts an
 *                           EEPROM byte write (the cell holds the value from then on, as in
 *                           simavr; a power cut during the 3.3 ms write keeps it);
 *   --command-vars T,D      data addresses of the master's cmd_ticks (4 x uint16) and cmd_duty
 *                           (4 x uint8), from its ELF's symbols;
 *   --coverage FILE         at the end: per board the flash byte addresses of every instruction
 *                           executed ("pcs N a b ..."), and the master's branch edges as AFL
 *                           counts them, a 16-bit hash of (previous, current) instruction
 *                           ("edges i j ...").
 *
 * Reading two counters a quantum and one bit per instruction cost nothing measurable. */
#include <stdlib.h>
#include <string.h>

#include "harness.h"

#define FLASH_BYTES 32768u
#define EDGES 65536u
#define FW_RX_OVERFLOWS 4u   /* offsets in struct fw_stats (firmware/firmware.h) */
#define FW_COMMANDS 12u

static FILE *event_log;
static uint32_t ticks_addr, duty_addr;
static uint16_t last_commands, last_overflows;
static int armed;   /* the counters read 0 since the last power-up (the start-up code ran) */
static const char *coverage_path;
int coverage_on;
static uint8_t pcs[N_BOARDS][FLASH_BYTES / 2];
static uint8_t edges[EDGES];
static uint32_t edge_prev;

void watch_open_events(const char *path)
{
    event_log = fopen(path, "w");
    if (!event_log) {
        die("cannot write", path);
    }
}

void watch_command_vars(const char *spec)
{
    char *end;
    ticks_addr = (uint32_t)strtoul(spec, &end, 0);
    if (*end != ',') {
        die("--command-vars wants TICKS,DUTY data addresses", spec);
    }
    duty_addr = (uint32_t)strtoul(end + 1, NULL, 0);
}

void watch_open_coverage(const char *path)
{
    coverage_path = path;
    coverage_on = 1;
}

static double now_s(void)
{
    return (double)H.now / F_CPU_HZ;
}

static uint16_t u16(const uint8_t *d)
{
    return (uint16_t)(d[0] | d[1] << 8);
}

void watch_power(int on)
{
    last_commands = last_overflows = 0;
    armed = 0;   /* simavr keeps the RAM across a reset: wait for the start-up code's clearing */
    if (event_log) {
        fprintf(event_log, "%.7f power %s\n", now_s(), on ? "on" : "off");
    }
}

void watch_eeprom(const board_t *b, uint64_t cycle, unsigned address, unsigned value)
{
    if (event_log) {
        fprintf(event_log, "%.7f eeprom %d %u %02x\n", (double)cycle / F_CPU_HZ, b->index + 1,
                address, value);
    }
}

/* Once a quantum: the master's counters, compared with the last seen. Both only grow while it
 * runs; after a power-up they count once the start-up code has cleared them. */
void watch_service(void)
{
    board_t *m = &H.boards[0];
    if (!event_log || !m->stats_addr || !m->powered || H.now < m->boot_at) {
        return;
    }
    const uint8_t *d = m->avr->data + m->stats_addr;
    uint16_t commands = u16(d + FW_COMMANDS), overflows = u16(d + FW_RX_OVERFLOWS);
    if (!armed) {
        armed = commands == 0 && overflows == 0;
        return;
    }
    if (commands != last_commands && commands != 0) {
        last_commands = commands;
        fprintf(event_log, "%.7f cmd %u", now_s(), commands);
        if (ticks_addr && duty_addr) {
            const uint8_t *t = m->avr->data + ticks_addr, *v = m->avr->data + duty_addr;
            fprintf(event_log, " $%05u,%02u,%05u,%02u,%05u,%02u,%05u,%02u#", u16(t), v[0],
                    u16(t + 2), v[1], u16(t + 4), v[2], u16(t + 6), v[3]);
        }
        fputc('\n', event_log);
    }
    if (overflows != last_overflows && overflows != 0) {
        last_overflows = overflows;
        fprintf(event_log, "%.7f overflow %u\n", now_s(), overflows);
    }
}

/* One executed instruction of board `b` that started at flash byte address `pc`. */
void watch_pc(const board_t *b, uint32_t pc)
{
    pcs[b->index][(pc >> 1) % (FLASH_BYTES / 2)] = 1;
    if (b->index == 0) {
        uint32_t cur = ((pc >> 1) * 2654435761u) >> 16;
        edges[(cur ^ edge_prev) % EDGES] = 1;
        edge_prev = cur >> 1;
    }
}

void watch_close(void)
{
    if (event_log) {
        fclose(event_log);
        event_log = NULL;
    }
    if (!coverage_path) {
        return;
    }
    FILE *f = fopen(coverage_path, "w");
    if (!f) {
        die("cannot write", coverage_path);
    }
    for (int i = 0; i < N_BOARDS; i++) {
        fprintf(f, "pcs %d", i + 1);
        for (uint32_t w = 0; w < FLASH_BYTES / 2; w++) {
            if (pcs[i][w]) {
                fprintf(f, " %x", w << 1);
            }
        }
        fputc('\n', f);
    }
    fprintf(f, "edges");
    for (uint32_t e = 0; e < EDGES; e++) {
        if (edges[e]) {
            fprintf(f, " %x", e);
        }
    }
    fputc('\n', f);
    fclose(f);
}
