/* One simulated board: its image loaded, powered on and off (EEPROM contents kept, with
 * --eeprom-dir also across processes), the data sheet's EEPROM write time, and its core run up to
 * a cycle with the time of every interrupt measured. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <simavr/avr_eeprom.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_hex.h>

#include "harness.h"

static void no_sleep(avr_t *avr, avr_cycle_count_t how_long)
{
    (void)avr;
    (void)how_long;   /* the harness paces time itself */
}

void die(const char *what, const char *detail)
{
    fprintf(stderr, "armfw-harness: %s: %s\n", what, detail);
    exit(2);
}

static void load_image(avr_t *avr, const char *path)
{
    size_t n = strlen(path);
    if (n > 4 && strcmp(path + n - 4, ".elf") == 0) {
        elf_firmware_t fw;
        memset(&fw, 0, sizeof fw);
        if (elf_read_firmware(path, &fw) != 0) {
            die("cannot read ELF", path);
        }
        avr_load_firmware(avr, &fw);
        return;
    }
    ihex_chunk_p chunks = NULL;
    int count = read_ihex_chunks(path, &chunks);
    if (count <= 0) {
        die("cannot read Intel hex", path);
    }
    for (int i = 0; i < count; i++) {
        if (chunks[i].baseaddr < 0x800000u) {
            avr_loadcode(avr, chunks[i].data, chunks[i].size, chunks[i].baseaddr);
        }
    }
    free_ihex_chunks(chunks);
}

static void eeprom_io(board_t *b, int set)
{
    avr_eeprom_desc_t d = {.ee = b->eeprom, .offset = 0, .size = EEPROM_BYTES};
    avr_ioctl(b->avr, set ? AVR_IOCTL_EEPROM_SET : AVR_IOCTL_EEPROM_GET, &d);
    if (!set && d.ee != b->eeprom) {
        memcpy(b->eeprom, d.ee, EEPROM_BYTES);
    }
}

static void eeprom_file(board_t *b, int save)
{
    if (!H.eeprom_dir) {
        return;
    }
    char path[4096];
    snprintf(path, sizeof path, "%s/joint%d.eep", H.eeprom_dir, b->index + 1);
    FILE *f = fopen(path, save ? "wb" : "rb");
    if (!f) {
        return;
    }
    if (save) {
        fwrite(b->eeprom, 1, EEPROM_BYTES, f);
    } else if (fread(b->eeprom, 1, EEPROM_BYTES, f) != EEPROM_BYTES) {
        memset(b->eeprom, 0xFF, EEPROM_BYTES);
    }
    fclose(f);
}

void board_power_on(board_t *b)
{
    avr_t *avr = b->avr;
    avr->cycle = H.now;
    avr_reset(avr);
    avr->sleep = no_sleep;
    eeprom_io(b, 1);
    twi_reset(b);
    b->boot_at = H.now + H.boot_cycles;
    b->powered = 1;
    b->isr_depth = 0;
    joint_attach(b);
}

void board_power_off(board_t *b)
{
    eeprom_io(b, 0);
    eeprom_file(b, 1);
    twi_reset(b);
    b->powered = 0;
}

void board_save(board_t *b)
{
    if (b->powered) {
        eeprom_io(b, 0);
        eeprom_file(b, 1);
    }
}

/* "eeprom blank" while unpowered: every cell back to 0xFF, as a programmer erasing the chip. */
void board_eeprom_blank(board_t *b)
{
    memset(b->eeprom, 0xFF, EEPROM_BYTES);
    b->eeprom_busy_until = 0;
    eeprom_file(b, 1);
}

/* simavr 1.6 completes an EEPROM write at once; the ATmega328P takes 3.3 ms per byte (data sheet,
 * tWD_EEPROM), during which EECR.EEPE reads 1 and the next EEPROM access waits (avr-libc polls
 * it). The harness keeps EEPE set for that long after each write. */
#define R_EECR 0x3F
#define R_EEDR 0x40
#define R_EEARL 0x41
#define R_EEARH 0x42
#define EEPE_BIT 0x02
#define EEPROM_WRITE_CYCLES (F_CPU_HZ / 1000 * 33 / 10)

static void eecr_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
    board_t *b = param;
    /* a write starts on EEPE 0 -> 1 with EEMPE set; a read-modify-write of EECR while busy
     * (SBI sees the EEPE this harness reports) starts nothing */
    int starting = (v & EEPE_BIT) && !(avr->data[addr] & EEPE_BIT) && (avr->data[addr] & 0x04)
        && avr->cycle >= b->eeprom_busy_until;
    b->eecr_w.c(avr, addr, v, b->eecr_w.param);
    avr->data[addr] &= (uint8_t)~EEPE_BIT;   /* busy is eeprom_busy_until's business alone */
    if (starting) {
        b->eeprom_busy_until = avr->cycle + EEPROM_WRITE_CYCLES;
        watch_eeprom(b, avr->cycle, avr->data[R_EEARL] | (avr->data[R_EEARH] & 0x03u) << 8,
                     avr->data[R_EEDR]);
    }
}

static uint8_t eecr_read(avr_t *avr, avr_io_addr_t addr, void *param)
{
    board_t *b = param;
    uint8_t v = b->eecr_r.c ? b->eecr_r.c(avr, addr, b->eecr_r.param) : avr->data[addr];
    return avr->cycle < b->eeprom_busy_until ? (uint8_t)(v | EEPE_BIT) : (uint8_t)(v & ~EEPE_BIT);
}

/* simavr 1.6 times a UART byte as 11 bits (it counts a parity bit that 8N1 has not), 93 us at
 * UBRR 16 with U2X instead of the chip's 85 us: bytes fed at the host's 115 200 baud then pile
 * up in its 64-byte input FIFO over a long stream and are lost there, and replies leave slowly.
 * After each baud write the byte time is set to the data sheet's: (1 + 8 + 1) bits of
 * (U2X ? 8 : 16) x (UBRR + 1) cycles. */
#define R_UBRR0L 0xC4
#define R_UBRR0H 0xC5
#define R_UCSR0A 0xC0
#define U2X0_BIT 0x02

static void ubrr_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
    board_t *b = NULL;
    for (int i = 0; i < N_BOARDS; i++) {
        if (H.boards[i].avr == avr) {
            b = &H.boards[i];
        }
    }
    int high = addr == AVR_DATA_TO_IO(R_UBRR0H);
    if (b->ubrr_w[high].c) {
        b->ubrr_w[high].c(avr, addr, v, b->ubrr_w[high].param);
    } else {
        avr->data[addr] = v;
    }
    (void)param;
    avr_uart_t *uart = b->uart;
    if (uart) {
        uint32_t ubrr = avr->data[R_UBRR0L] | (uint32_t)(avr->data[R_UBRR0H] & 0x0F) << 8;
        uint32_t per_bit = (avr->data[R_UCSR0A] & U2X0_BIT ? 8u : 16u) * (ubrr + 1);
        uart->cycles_per_byte = 10u * per_bit;
    }
}

static void fix_uart_timing(board_t *b)
{
    for (int high = 0; high < 2; high++) {
        avr_io_addr_t io = AVR_DATA_TO_IO(high ? R_UBRR0H : R_UBRR0L);
        b->ubrr_w[high].c = b->avr->io[io].w.c;
        b->ubrr_w[high].param = b->avr->io[io].w.param;
        if (b->avr->io[io].w.param && !b->uart) {
            b->uart = b->avr->io[io].w.param;   /* simavr's UART registered this write */
        }
        b->avr->io[io].w.c = ubrr_write;
        b->avr->io[io].w.param = b;
    }
}

void board_setup(board_t *b)
{
    b->avr = avr_make_mcu_by_name("atmega328p");
    if (!b->avr) {
        die("simavr has no core", "atmega328p");
    }
    avr_init(b->avr);
    b->avr->frequency = F_CPU_HZ;
    b->avr->log = 0;
    load_image(b->avr, b->firmware);
    b->avr->frequency = F_CPU_HZ;
    memset(b->eeprom, 0xFF, EEPROM_BYTES);
    eeprom_file(b, 0);
    twi_attach(b);
    avr_io_addr_t eecr = AVR_DATA_TO_IO(R_EECR);
    b->eecr_w.c = b->avr->io[eecr].w.c;
    b->eecr_w.param = b->avr->io[eecr].w.param;
    b->eecr_r.c = b->avr->io[eecr].r.c;
    b->eecr_r.param = b->avr->io[eecr].r.param;
    b->avr->io[eecr].w.c = eecr_write;
    b->avr->io[eecr].w.param = b;
    b->avr->io[eecr].r.c = eecr_read;
    b->avr->io[eecr].r.param = b;
    if (b->index == 0) {
        fix_uart_timing(b);
        uint32_t flags = 0;
        avr_ioctl(b->avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
        flags &= ~(uint32_t)AVR_UART_FLAG_STDIO;
        avr_ioctl(b->avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
        avr_irq_register_notify(avr_io_getirq(b->avr, AVR_IOCTL_UART_GETIRQ('0'),
                                              UART_IRQ_OUTPUT), uart_out, NULL);
    }
    board_power_on(b);
}

static int is_reti(avr_t *avr, avr_flashaddr_t pc)
{
    return avr->flash[pc] == 0x18 && avr->flash[pc + 1] == 0x95;
}

/* Account one executed instruction that started at `pc`: an interrupt entered (the core jumped
 * onto a vector) or left (RETI: its time, from the vector to here). */
static void time_interrupts(board_t *b, avr_flashaddr_t pc, int ending)
{
    avr_t *avr = b->avr;
    if (ending) {
        isr_stat_t *s = &b->isr[b->isr_stack[--b->isr_depth]];
        uint64_t d = avr->cycle - s->start;
        s->count++;
        s->total += d;
        if (d > s->worst) {
            s->worst = d;
        }
    } else if (avr->pc < 26 * 4 && avr->pc != pc + 2 && (avr->pc & 3) == 0 && avr->pc
               && b->isr_depth < 4) {
        uint8_t v = (uint8_t)(avr->pc / 4);
        b->isr_stack[b->isr_depth++] = v;
        b->isr[v].start = avr->cycle;
    }
}

/* Run one core up to the global cycle `until`, timing its interrupts. */
void board_run(board_t *b, uint64_t until)
{
    avr_t *avr = b->avr;
    if (!b->powered || H.now < b->boot_at) {
        avr->cycle = until;
        return;
    }
    while (avr->cycle < until) {
        if (avr->state == cpu_Sleeping && !avr_has_pending_interrupts(avr)) {
            /* asleep: skip to its next timer, or to the end of the quantum, whichever is first
             * (an interrupt the harness raises in between wakes it at the right cycle) */
            avr_cycle_timer_slot_p t = avr->cycle_timers.timer;
            if (!t || t->when >= until) {
                avr->cycle = until;
                break;
            }
            if (t->when > avr->cycle) {
                avr->cycle = t->when;
            }
            avr_cycle_timer_process(avr);
            continue;
        }
        if (avr->state == cpu_Sleeping) {
            avr->state = cpu_Running;   /* an interrupt is pending: wake up */
        }
        avr_flashaddr_t pc = avr->pc;
        if (avr->flash[pc] == 0x88 && avr->flash[pc + 1] == 0x95) {
            /* SLEEP, done here: simavr's would run the clock on to the next timer in the same
             * call, past interrupts the harness raises in between */
            if (avr->data[0x53] & 0x01) {   /* SMCR.SE */
                avr->state = cpu_Sleeping;
            }
            avr->pc += 2;
            avr->cycle += 1;
            continue;
        }
        int ending = b->isr_depth > 0 && is_reti(avr, pc);
        avr->run(avr);
        b->instructions++;
        if (coverage_on) {
            watch_pc(b, pc);
        }
        time_interrupts(b, pc, ending);
        if (avr->state == cpu_Done || avr->state == cpu_Crashed) {
            fprintf(stderr, "armfw-harness: joint %d stopped (state %d) at pc 0x%x\n",
                    b->index + 1, avr->state, (unsigned)avr->pc);
            b->powered = 0;
            return;
        }
    }
}
