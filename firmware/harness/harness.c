/* armfw-harness: the reference firmware (or a lab's own, built for firmware/pins.h) on four
 * simulated ATmega328P in lockstep (docs/firmware.md).
 *
 *   armfw-harness [--pty] [--speed realtime|max] [--seconds S] [--eeprom-dir DIR] [--boot-ms MS]
 *                 [--send TEXT] [--script FILE] [--reply-log FILE] [--isr-vector N]
 *                 [--control FIFO]
 *                 --board FILE,LOWER,UPPER,HALL,NUM,DEN,MOTOR[,STATS] (four times, joint 1..4)
 *
 * FILE is an Intel hex or ELF image; LOWER/UPPER/HALL/MOTOR are microsteps (hard limits, Hall
 * position, start position); NUM/DEN encoder counts per microstep; STATS the data address of the
 * firmware's fw_stats (0: unknown). Joint 1's UART is served on a pty ("pty PATH" on stdout).
 * Commands on stdin (or --control FIFO), one per line: "power off", "power on", "stats" (prints
 * "stats {json}"), "quit"; the end of stdin quits too unless --seconds is given. EEPROM
 * contents survive a power cut and, with --eeprom-dir, the process.
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <simavr/avr_eeprom.h>
#include <simavr/avr_uart.h>
#include <simavr/sim_elf.h>
#include <simavr/sim_hex.h>

#include "harness.h"

harness_t H;

static const char *eeprom_dir;
static int max_speed;
static double stop_after_s = -1.0;
static uint64_t boot_cycles = F_CPU_HZ / 10;   /* 0.1 s, as emulator.boot_s */

static void no_sleep(avr_t *avr, avr_cycle_count_t how_long)
{
    (void)avr;
    (void)how_long;   /* the harness paces time itself */
}

static void die(const char *what, const char *detail)
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
    if (!eeprom_dir) {
        return;
    }
    char path[4096];
    snprintf(path, sizeof path, "%s/joint%d.eep", eeprom_dir, b->index + 1);
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

static void power_on_board(board_t *b)
{
    avr_t *avr = b->avr;
    avr->cycle = H.now;
    avr_reset(avr);
    avr->sleep = no_sleep;
    eeprom_io(b, 1);
    twi_reset(b);
    b->boot_at = H.now + boot_cycles;
    b->powered = 1;
    b->isr_depth = 0;
    joint_attach(b);
}

static void power_off_board(board_t *b)
{
    eeprom_io(b, 0);
    eeprom_file(b, 1);
    twi_reset(b);
    b->powered = 0;
}

/* simavr 1.6 completes an EEPROM write at once; the ATmega328P takes 3.3 ms per byte (data sheet,
 * tWD_EEPROM), during which EECR.EEPE reads 1 and the next EEPROM access waits (avr-libc polls
 * it). The harness keeps EEPE set for that long after each write. */
#define R_EECR 0x3F
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
    }
}

static uint8_t eecr_read(avr_t *avr, avr_io_addr_t addr, void *param)
{
    board_t *b = param;
    uint8_t v = b->eecr_r.c ? b->eecr_r.c(avr, addr, b->eecr_r.param) : avr->data[addr];
    return avr->cycle < b->eeprom_busy_until ? (uint8_t)(v | EEPE_BIT) : (uint8_t)(v & ~EEPE_BIT);
}

static void setup_board(board_t *b)
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
    b->eecr_w.c = b->avr->io[AVR_DATA_TO_IO(R_EECR)].w.c;
    b->eecr_w.param = b->avr->io[AVR_DATA_TO_IO(R_EECR)].w.param;
    b->eecr_r.c = b->avr->io[AVR_DATA_TO_IO(R_EECR)].r.c;
    b->eecr_r.param = b->avr->io[AVR_DATA_TO_IO(R_EECR)].r.param;
    b->avr->io[AVR_DATA_TO_IO(R_EECR)].w.c = eecr_write;
    b->avr->io[AVR_DATA_TO_IO(R_EECR)].w.param = b;
    b->avr->io[AVR_DATA_TO_IO(R_EECR)].r.c = eecr_read;
    b->avr->io[AVR_DATA_TO_IO(R_EECR)].r.param = b;
    if (b->index == 0) {
        uint32_t flags = 0;
        avr_ioctl(b->avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
        flags &= ~(uint32_t)AVR_UART_FLAG_STDIO;
        avr_ioctl(b->avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
        avr_irq_register_notify(avr_io_getirq(b->avr, AVR_IOCTL_UART_GETIRQ('0'),
                                              UART_IRQ_OUTPUT), uart_out, NULL);
    }
    power_on_board(b);
}

static int is_reti(avr_t *avr, avr_flashaddr_t pc)
{
    return avr->flash[pc] == 0x18 && avr->flash[pc + 1] == 0x95;
}

/* Run one core up to the global cycle `until`, timing its control interrupt. */
static void run_board(board_t *b, uint64_t until)
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
        if (ending) {   /* RETI: the innermost interrupt's time, from its vector to here */
            isr_stat_t *s = &b->isr[b->isr_stack[--b->isr_depth]];
            uint64_t d = avr->cycle - s->start;
            s->count++;
            s->total += d;
            if (d > s->worst) {
                s->worst = d;
            }
        } else if (avr->pc < 26 * 4 && avr->pc != pc + 2 && (avr->pc & 3) == 0 && avr->pc
                   && b->isr_depth < 4) {   /* jumped onto a vector: an interrupt */
            uint8_t v = (uint8_t)(avr->pc / 4);
            b->isr_stack[b->isr_depth++] = v;
            b->isr[v].start = avr->cycle;
        }
        if (avr->state == cpu_Done || avr->state == cpu_Crashed) {
            fprintf(stderr, "armfw-harness: joint %d stopped (state %d) at pc 0x%x\n",
                    b->index + 1, avr->state, (unsigned)avr->pc);
            b->powered = 0;
            return;
        }
    }
}

static double wall_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static int control(const char *line, double wall_s)
{
    if (strncmp(line, "power off", 9) == 0) {
        for (int i = 0; i < N_BOARDS; i++) {
            power_off_board(&H.boards[i]);
        }
    } else if (strncmp(line, "power on", 8) == 0) {
        for (int i = 0; i < N_BOARDS; i++) {
            if (!H.boards[i].powered) {
                power_on_board(&H.boards[i]);
            }
        }
    } else if (strncmp(line, "stats", 5) == 0) {
        print_stats(wall_s);
    } else if (strncmp(line, "quit", 4) == 0) {
        return 0;
    } else {
        fprintf(stderr, "armfw-harness: unknown command: %s", line);
    }
    return 1;
}

typedef struct line_reader_t {
    int fd;
    char line[256];
    size_t len;
} line_reader_t;

static line_reader_t control_in = {0, {0}, 0}, control_fifo = {-1, {0}, 0};

/* Run the complete command lines readable on `r`; 0 when told to quit or, for stdin, when the
 * parent closed it (no orphan harness) unless the run has a --seconds limit. */
static int read_commands(line_reader_t *r, double wall_s)
{
    char buf[256];
    ssize_t n = read(r->fd, buf, sizeof buf);
    if (n == 0 && r == &control_in && stop_after_s < 0) {
        return 0;
    }
    for (ssize_t i = 0; i < n; i++) {
        if (buf[i] == '\n' || r->len == sizeof r->line - 1) {
            r->line[r->len] = 0;
            r->len = 0;
            if (!control(r->line, wall_s)) {
                return 0;
            }
        } else {
            r->line[r->len++] = buf[i];
        }
    }
    return 1;
}

/* Read the pty and the control inputs without blocking; 0 when told to quit. */
static int poll_io(double wall_s)
{
    fd_set fds;
    FD_ZERO(&fds);
    FD_SET(0, &fds);
    int top = 0;
    if (H.pty_fd >= 0) {
        FD_SET(H.pty_fd, &fds);
        top = H.pty_fd > top ? H.pty_fd : top;
    }
    if (control_fifo.fd >= 0) {
        FD_SET(control_fifo.fd, &fds);
        top = control_fifo.fd > top ? control_fifo.fd : top;
    }
    struct timeval tv = {0, 0};
    if (select(top + 1, &fds, NULL, NULL, &tv) <= 0) {
        return 1;
    }
    if (H.pty_fd >= 0 && FD_ISSET(H.pty_fd, &fds)) {
        uint8_t buf[512];
        ssize_t n = read(H.pty_fd, buf, sizeof buf);
        for (ssize_t i = 0; i < n; i++) {
            unsigned next = (H.rx_head + 1) % sizeof H.rx_queue;
            if (next != H.rx_tail) {
                H.rx_queue[H.rx_head] = buf[i];
                H.rx_head = next;
            }
        }
    }
    if (control_fifo.fd >= 0 && FD_ISSET(control_fifo.fd, &fds)
        && !read_commands(&control_fifo, wall_s)) {
        return 0;
    }
    return !FD_ISSET(0, &fds) || read_commands(&control_in, wall_s);
}

static void open_pty(void)
{
    H.pty_fd = posix_openpt(O_RDWR | O_NOCTTY);
    if (H.pty_fd < 0 || grantpt(H.pty_fd) || unlockpt(H.pty_fd)) {
        die("cannot open a pty", strerror(errno));
    }
    const char *name = ptsname(H.pty_fd);
    int slave = open(name, O_RDWR | O_NOCTTY);   /* kept open: a client may close and reopen */
    struct termios t;
    tcgetattr(slave, &t);
    cfmakeraw(&t);
    tcsetattr(slave, TCSANOW, &t);
    fcntl(H.pty_fd, F_SETFL, O_NONBLOCK);
    printf("pty %s\n", name);
    fflush(stdout);
}

static void parse_board(board_t *b, char *spec)
{
    char *fields[8] = {0};
    int n = 0;
    for (char *tok = strtok(spec, ","); tok && n < 8; tok = strtok(NULL, ",")) {
        fields[n++] = tok;
    }
    if (n < 7) {
        die("--board wants FILE,LOWER,UPPER,HALL,NUM,DEN,MOTOR[,STATS]", spec);
    }
    b->firmware = fields[0];
    b->joint.lower_steps = strtoll(fields[1], NULL, 0);
    b->joint.upper_steps = strtoll(fields[2], NULL, 0);
    b->joint.hall_step = strtoll(fields[3], NULL, 0);
    b->joint.counts_num = (int32_t)strtol(fields[4], NULL, 0);
    b->joint.counts_den = (int32_t)strtol(fields[5], NULL, 0);
    b->joint.motor_steps = strtoll(fields[6], NULL, 0);
    b->stats_addr = n > 7 ? (uint32_t)strtoul(fields[7], NULL, 0) : 0;
    if (b->joint.counts_den <= 0 || b->joint.counts_num <= 0) {
        die("encoder counts per step must be positive", fields[4]);
    }
}

int main(int argc, char **argv)
{
    int boards = 0, pty = 0;
    H.pty_fd = -1;
    H.isr_vector = 11;   /* TIMER1_COMPA_vect */
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--pty") == 0) {
            pty = 1;
        } else if (strcmp(a, "--speed") == 0 && v) {
            max_speed = strcmp(v, "max") == 0;
            i++;
        } else if (strcmp(a, "--seconds") == 0 && v) {
            stop_after_s = atof(v);
            i++;
        } else if (strcmp(a, "--eeprom-dir") == 0 && v) {
            eeprom_dir = v;
            i++;
        } else if (strcmp(a, "--boot-ms") == 0 && v) {
            boot_cycles = (uint64_t)(atof(v) * F_CPU_HZ / 1000.0);
            i++;
        } else if (strcmp(a, "--isr-vector") == 0 && v) {
            H.isr_vector = (unsigned)atoi(v) % 26;
            i++;
        } else if (strcmp(a, "--send") == 0 && v) {
            for (const char *c = argv[++i]; *c; c++) {   /* bytes for joint 1's UART at boot */
                H.rx_queue[H.rx_head] = (uint8_t)*c;
                H.rx_head = (H.rx_head + 1) % sizeof H.rx_queue;
            }
            H.rx_next_at = boot_cycles + F_CPU_HZ / 1000;
        } else if (strcmp(a, "--control") == 0 && v) {
            /* a FIFO taking the same commands as stdin (e.g. a bench's power commands) */
            control_fifo.fd = open(argv[++i], O_RDWR | O_NONBLOCK);   /* RDWR: no EOF churn */
            if (control_fifo.fd < 0) {
                die("cannot open the control FIFO", v);
            }
        } else if (strcmp(a, "--script") == 0 && v) {
            load_script(argv[++i]);
        } else if (strcmp(a, "--reply-log") == 0 && v) {
            reply_log = fopen(argv[++i], "w");
            if (!reply_log) {
                die("cannot write", v);
            }
        } else if (strcmp(a, "--board") == 0 && v && boards < N_BOARDS) {
            H.boards[boards].index = boards;
            parse_board(&H.boards[boards], argv[++i]);
            boards++;
        } else {
            die("unknown or incomplete option", a);
        }
    }
    if (boards != N_BOARDS) {
        die("four --board options are needed", "joint 1..4");
    }
    fcntl(0, F_SETFL, O_NONBLOCK);
    if (pty) {
        open_pty();
    }
    for (int i = 0; i < N_BOARDS; i++) {
        setup_board(&H.boards[i]);
    }
    int announced = 0;   /* "ready" once the boards have booted: an arm powered before use */
    double wall0 = wall_now();
    double pace0 = wall0;   /* wall time that simulated time 0 is paced against */
    const uint64_t poll_every = F_CPU_HZ / 1000;   /* 1 ms of simulated time */
    uint64_t next_poll = poll_every;
    int running = 1;
    while (running) {
        uint64_t until = H.now + QUANTUM_CYCLES;
        for (int i = 0; i < N_BOARDS; i++) {
            joint_service(&H.boards[i], H.now);
            run_board(&H.boards[i], until);
        }
        H.now = until;
        twi_service(H.now);
        script_due();
        uart_in();
        if (!announced && H.now >= boot_cycles + F_CPU_HZ / 1000) {
            announced = 1;
            printf("ready\n");
            fflush(stdout);
        }
        if (H.now >= next_poll) {
            next_poll += poll_every;
            double wall = wall_now() - wall0;
            running = poll_io(wall);
            if (stop_after_s >= 0 && (double)H.now / F_CPU_HZ >= stop_after_s) {
                print_stats(wall);
                running = 0;
            }
            if (!max_speed) {
                double ahead = (double)H.now / F_CPU_HZ - (wall_now() - pace0);
                if (ahead > 0.0005) {
                    struct timespec ts = {0, (long)(ahead * 1e9)};
                    nanosleep(&ts, NULL);
                } else if (ahead < -0.05) {   /* fell behind (busy machine): drop the lag */
                    pace0 -= ahead;
                    H.lag_drops++;
                }
            }
        }
    }
    if (reply_log) {
        fclose(reply_log);
    }
    for (int i = 0; i < N_BOARDS; i++) {
        if (H.boards[i].powered) {
            eeprom_io(&H.boards[i], 0);
            eeprom_file(&H.boards[i], 1);
        }
    }
    return 0;
}
