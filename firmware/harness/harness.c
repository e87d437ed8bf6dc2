/* armfw-harness: the reference firmware (or a lab's own, built for firmware/pins.h) on four
 * simulated ATmega328P in lockstep (docs/firmware.md).
 *
 *   armfw-harness [--pty] [--speed realtime|max] [--lockstep] [--seconds S] [--eeprom-dir DIR]
 *                 [--boot-ms MS] [--send TEXT] [--script FILE] [--reply-log FILE] [--isr-vector N]
 *                 [--control FIFO] [--event-log FILE] [--command-vars T,D] [--coverage FILE]
 *                 --board FILE,LOWER,UPPER,HALL,NUM,DEN,MOTOR[,STATS] (four times, joint 1..4)
 *
 * FILE is an Intel hex or ELF image; LOWER/UPPER/HALL/MOTOR are microsteps (hard limits, Hall
 * position, start position); NUM/DEN encoder counts per microstep; STATS the data address of the
 * firmware's fw_stats (0: unknown). Joint 1's UART is served on a pty ("pty PATH" on stdout).
 * Commands on stdin (or --control FIFO), one per line (control.c): "power off", "power on",
 * "eeprom blank", "home", "stats" (prints "stats {json}"), "quit"; the end of stdin quits too
 * unless --seconds is given. EEPROM contents survive a power cut and, with --eeprom-dir, the
 * process.
 *
 * --event-log, --command-vars and --coverage are for the differential fuzzer (watch.c).
 *
 * --lockstep: no pty and no clock of its own; a host on stdin/stdout says how far to run and gets
 * joint 1's UART bytes back with the simulated time they left (lockstep.c), so the host's clock
 * can follow the boards' as fast as they run.
 *
 * This file: the options, one lockstep quantum and the free-running loop with its real-time
 * pacing. board.c runs a core, twi_bus.c the I2C bus, joint.c the joints, uart.c joint 1's UART,
 * control.c the pty and the commands, lockstep.c the host-driven mode, stats.c the figures.
 */
#define _GNU_SOURCE
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>

#include "harness.h"

harness_t H;

static int max_speed;
static int lockstep;

/* A lag behind the wall clock longer than this is given up instead of caught up (the process was
 * stopped, e.g. suspended or in a debugger: a burst of seconds of replies would help nobody). */
#define LAG_GIVE_UP_S 2.0
/* Behind by more than this counts as behind in the figures (one poll period of slack). */
#define LAG_SLACK_S 0.001

static double wall_now(void)
{
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return ts.tv_sec + ts.tv_nsec * 1e-9;
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

static void parse_options(int argc, char **argv)
{
    int boards = 0, pty = 0;
    for (int i = 1; i < argc; i++) {
        const char *a = argv[i];
        const char *v = i + 1 < argc ? argv[i + 1] : NULL;
        if (strcmp(a, "--pty") == 0) {
            pty = 1;
        } else if (strcmp(a, "--speed") == 0 && v) {
            max_speed = strcmp(v, "max") == 0;
            i++;
        } else if (strcmp(a, "--lockstep") == 0) {
            lockstep = 1;
        } else if (strcmp(a, "--seconds") == 0 && v) {
            H.stop_after_s = atof(v);
            i++;
        } else if (strcmp(a, "--eeprom-dir") == 0 && v) {
            H.eeprom_dir = v;
            i++;
        } else if (strcmp(a, "--boot-ms") == 0 && v) {
            H.boot_cycles = (uint64_t)(atof(v) * F_CPU_HZ / 1000.0);
            i++;
        } else if (strcmp(a, "--isr-vector") == 0 && v) {
            H.isr_vector = (unsigned)atoi(v) % 26;
            i++;
        } else if (strcmp(a, "--send") == 0 && v) {
            const char *text = argv[++i];   /* bytes for joint 1's UART, 1 ms after boot */
            uart_queue((const uint8_t *)text, strlen(text));
            H.rx_queued_at = H.boot_cycles + F_CPU_HZ / 1000;
        } else if (strcmp(a, "--control") == 0 && v) {
            /* a FIFO taking the same commands as stdin (e.g. a bench's power commands) */
            open_control_fifo(argv[++i]);
        } else if (strcmp(a, "--script") == 0 && v) {
            load_script(argv[++i]);
        } else if (strcmp(a, "--event-log") == 0 && v) {
            watch_open_events(argv[++i]);
        } else if (strcmp(a, "--command-vars") == 0 && v) {
            watch_command_vars(argv[++i]);
        } else if (strcmp(a, "--coverage") == 0 && v) {
            watch_open_coverage(argv[++i]);
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
    if (pty && lockstep) {
        die("--pty and --lockstep exclude each other", "the lockstep host is stdin/stdout");
    }
    if (pty) {
        open_pty();
    }
}

/* Real-time pacing, every simulated millisecond: ahead of the wall clock, sleep; behind (the
 * machine gave the harness too little CPU), run on without sleeping until caught up, so the arm's
 * clock stays the wall clock (an arm that ran slow would miss the host's deadlines) and the host
 * sees the late replies in a burst. The lag is declared in the figures. */
static void pace(double *pace0, double *last_wall)
{
    double wall = wall_now();
    double ahead = (double)H.now / F_CPU_HZ - (wall - *pace0);
    if (ahead > 0.0005) {
        struct timespec ts = {0, (long)(ahead * 1e9)};
        nanosleep(&ts, NULL);
    } else if (ahead < -LAG_GIVE_UP_S) {
        *pace0 -= ahead;
        H.lag_drops++;
        H.lag_dropped_s -= ahead;
    } else if (ahead < -LAG_SLACK_S) {
        H.behind_s += wall - *last_wall;
        if (-ahead > H.lag_max_s) {
            H.lag_max_s = -ahead;
        }
    }
    *last_wall = wall;
}

/* One quantum of the four cores in lockstep, then the bus, the script, the host's UART bytes
 * and the fuzzer's watch catch up with it. */
void harness_step(void)
{
    uint64_t until = H.now + QUANTUM_CYCLES;
    for (int i = 0; i < N_BOARDS; i++) {
        joint_service(&H.boards[i], H.now);
        board_run(&H.boards[i], until);
    }
    H.now = until;
    twi_service(H.now);
    script_due();
    uart_in();
    watch_service();
}

int main(int argc, char **argv)
{
    H.pty_fd = -1;
    H.isr_vector = 11;   /* TIMER1_COMPA_vect */
    H.stop_after_s = -1.0;
    H.boot_cycles = F_CPU_HZ / 10;   /* 0.1 s, as emulator.boot_s */
    parse_options(argc, argv);
    for (int i = 0; i < N_BOARDS; i++) {
        board_setup(&H.boards[i]);
    }
    if (!lockstep) {
        fcntl(0, F_SETFL, O_NONBLOCK);
    }
    int announced = 0;   /* "ready" once the boards have booted: an arm powered before use */
    double wall0 = wall_now();
    double pace0 = wall0;   /* wall time that simulated time 0 is paced against */
    double last_wall = wall0;
    const uint64_t poll_every = F_CPU_HZ / 1000;   /* 1 ms of simulated time */
    uint64_t next_poll = poll_every;
    int running = !lockstep;
    if (lockstep) {
        lockstep_serve();
    }
    while (running) {
        harness_step();
        if (!announced && H.now >= H.boot_cycles + F_CPU_HZ / 1000) {
            announced = 1;
            printf("ready\n");
            fflush(stdout);
        }
        if (H.now >= next_poll) {
            next_poll += poll_every;
            double wall = wall_now() - wall0;
            running = poll_io(wall);
            if (H.stop_after_s >= 0 && (double)H.now / F_CPU_HZ >= H.stop_after_s) {
                print_stats(wall);
                running = 0;
            }
            if (!max_speed) {
                pace(&pace0, &last_wall);
            }
        }
    }
    pty_flush();
    watch_close();
    if (reply_log) {
        fclose(reply_log);
    }
    for (int i = 0; i < N_BOARDS; i++) {
        board_save(&H.boards[i]);
    }
    return 0;
}
