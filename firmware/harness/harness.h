/* The simavr harness: four ATmega328P cores in lockstep on one simulated I2C bus, each driving a
 * joint model through its STEP/DIR pins (docs/firmware.md). */
#ifndef ARMFW_HARNESS_H
#define ARMFW_HARNESS_H

#include <stdint.h>
#include <stdio.h>

#include <simavr/sim_avr.h>
#include <simavr/sim_interrupts.h>
#include <simavr/sim_io.h>

struct avr_uart_t;

#define N_BOARDS 4
#define F_CPU_HZ 16000000u
#define QUANTUM_CYCLES 32u       /* lockstep granularity: 2 us */
#define EEPROM_BYTES 1024u
#define PIN_QUEUE 64u

typedef struct pin_event_t {
    uint64_t at;                 /* cycle */
    uint8_t pin, level;          /* port D bit */
} pin_event_t;

/* One joint's mechanics: microsteps, encoder on the motor shaft, Hall, hard limits. */
typedef struct joint_t {
    int64_t motor_steps;
    int64_t lower_steps, upper_steps, hall_step;
    int32_t counts_num, counts_den;  /* encoder counts per microstep, 5/4 by default */
    uint8_t gray;                    /* encoder A/B state, 0..3 = 00 01 11 10 */
    uint8_t hall_level;
    uint8_t step_level, dir_level;
    uint64_t steps, blocked;
    uint64_t last_event;             /* cycle of the last queued pin change */
    pin_event_t queue[PIN_QUEUE];
    unsigned q_head, q_tail;
} joint_t;

typedef struct twi_t {
    uint8_t addressed;       /* master: address byte sent in this transaction */
    uint8_t sla;             /* master: SLA+R/W of this transaction */
} twi_t;

typedef struct isr_stat_t {
    uint64_t count, total, worst;
    uint64_t start;
    uint8_t inside;
} isr_stat_t;

typedef struct board_t {
    int index;                       /* 0..3: joint index - 1 */
    avr_t *avr;
    avr_int_vector_t *twi_vec;
    const char *firmware;
    int powered;
    uint64_t boot_at;                /* held in reset until this cycle */
    uint8_t eeprom[EEPROM_BYTES];
    joint_t joint;
    twi_t twi;
    isr_stat_t isr[26];              /* per interrupt vector of the ATmega328P */
    int isr_depth;
    uint8_t isr_stack[4];
    uint32_t stats_addr;             /* data address of fw_stats, 0 if unknown */
    uint64_t instructions;           /* executed (a busy core costs the harness its time) */
    uint64_t eeprom_busy_until;      /* cycle: EEPE reads 1 until then */
    struct {
        avr_io_write_t c;
        void *param;
    } eecr_w;
    struct {
        avr_io_read_t c;
        void *param;
    } eecr_r;                        /* simavr's own EECR handlers, called by the harness's */
    struct {
        avr_io_write_t c;
        void *param;
    } ubrr_w[2];                     /* simavr's UBRR0L/H handlers (board.c: UART byte time) */
    struct avr_uart_t *uart;         /* joint 1's simavr UART */
} board_t;

/* The bus and the harness's global state */
typedef struct harness_t {
    board_t boards[N_BOARDS];
    uint64_t now;                    /* global cycle */
    /* UART (board 0) */
    int pty_fd;
    uint8_t rx_queue[4096];
    unsigned rx_head, rx_tail;
    uint64_t rx_next_at;             /* when the line is free for the next byte */
    uint64_t rx_queued_at;           /* when the host queued bytes to an empty queue */
    uint64_t rx_bytes, rx_lost_power;
    uint64_t tx_bytes, tx_lost, replies;
    uint64_t last_reply_at, period_min, period_max, period_sum, period_n;
    /* I2C */
    uint64_t i2c_transactions, i2c_naks, i2c_start_at, i2c_min, i2c_max, i2c_sum;
    /* real-time pacing (harness.c) */
    double lag_max_s;                /* worst lag behind the wall clock */
    double behind_s;                 /* wall time spent catching up a lag */
    uint64_t lag_drops;              /* lags too long to catch up (the process was stopped) */
    double lag_dropped_s;            /* simulated time given up by those */
    unsigned isr_vector;             /* the control interrupt's vector (11: TIMER1_COMPA) */
    /* options */
    const char *eeprom_dir;          /* --eeprom-dir: jointN.eep kept there, or NULL */
    uint64_t boot_cycles;            /* --boot-ms: held in reset this long after power-up */
    double stop_after_s;             /* --seconds, < 0 without */
} harness_t;

extern harness_t H;

void die(const char *what, const char *detail);

void board_setup(board_t *b);
void board_power_on(board_t *b);
void board_power_off(board_t *b);
void board_save(board_t *b);
void board_eeprom_blank(board_t *b);
void board_run(board_t *b, uint64_t until);

void harness_step(void);
int harness_command(const char *line, double wall_s);

void lockstep_serve(void);
int lockstep_put(uint8_t c);

void open_pty(void);
void open_control_fifo(const char *path);
void pty_put(uint8_t c);
void pty_flush(void);
int poll_io(double wall_s);

void twi_attach(board_t *b);
void twi_reset(board_t *b);
void twi_service(uint64_t now);
int twi_busy(void);

extern FILE *reply_log;

void load_script(const char *path);
void uart_queue(const uint8_t *bytes, size_t n);
void power_all(int on);
void script_due(void);
void uart_out(struct avr_irq_t *irq, uint32_t value, void *param);
void uart_in(void);
void print_stats(double wall_s);

void watch_open_events(const char *path);
void watch_command_vars(const char *spec);
void watch_open_coverage(const char *path);
void watch_power(int on);
void watch_eeprom(const board_t *b, uint64_t cycle, unsigned address, unsigned value);
void watch_service(void);
void watch_pc(const board_t *b, uint32_t pc);
void watch_close(void);
extern int coverage_on;

void joint_attach(board_t *b);
void joint_service(board_t *b, uint64_t now);
void joint_home(board_t *b);

#endif
