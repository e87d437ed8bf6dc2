/* The I2C bus of the four boards, routed by the harness.
 *
 * simavr 1.6 cannot join two cores' TWI (buserror/simavr#369) and its slave mode misbehaves (fixed
 * upstream later, PR #452), so the harness takes over each core's TWI registers (TWCR, TWSR, TWDR)
 * and runs the ATmega328P's TWI state machine itself, master and slave side, on one shared bus:
 * START and STOP take one bit time, each byte nine (eight bits and the ACK), at the bit rate the
 * master's TWBR/TWPS give (160 cycles = 10 us at 100 kHz). A slave that has TWINT set holds SCL
 * low (clock stretching): the master's next byte starts when the slave's firmware clears TWINT.
 * The status codes are the data sheet's (util/twi.h).
 */
#include <stdio.h>
#include <stdlib.h>

#include <simavr/sim_io.h>

#include "harness.h"

#define R_TWBR 0xB8
#define R_TWSR 0xB9
#define R_TWAR 0xBA
#define R_TWDR 0xBB
#define R_TWCR 0xBC
#define TWINT 0x80
#define TWEA 0x40
#define TWSTA 0x20
#define TWSTO 0x10
#define TWEN 0x04
#define TWI_VECTOR 24

enum { OP_NONE, OP_START, OP_ADDR, OP_WRITE, OP_READ, OP_STOP };

static struct {
    int owner;          /* master board, -1 when the bus is free */
    int slave;          /* addressed slave board, -1 if none */
    int reading;
    int stretch;        /* board holding SCL low (a slave whose TWINT is set), -1 if none */
    int op, running, op_master, op_ack;
    uint8_t byte;
    uint64_t due;
} bus = {-1, -1, 0, -1, OP_NONE, 0, -1, 0, 0, 0};

int twi_busy(void)
{
    return bus.owner >= 0 || bus.op != OP_NONE;
}

static int trace = -1;

static void set_status(board_t *b, uint8_t status)
{
    if (trace < 0) {
        trace = getenv("ARMFW_TWI_TRACE") != NULL;
    }
    if (trace) {
        fprintf(stderr, "twi %llu joint %d status %02x\n", (unsigned long long)H.now,
                b->index + 1, status);
    }
    avr_t *avr = b->avr;
    avr->data[R_TWSR] = (avr->data[R_TWSR] & 0x07) | status;
    avr_raise_interrupt(avr, b->twi_vec);
    avr->data[R_TWCR] |= TWINT;
}

static void twcr_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
    board_t *b = param;
    uint8_t old = avr->data[addr];
    if (trace > 0) {
        fprintf(stderr, "twi %llu joint %d twcr <- %02x (was %02x)\n",
                (unsigned long long)H.now, b->index + 1, v, old);
    }
    avr->data[addr] = (v & 0x77) | (old & TWINT);
    if (!(v & TWEN)) {
        avr_clear_interrupt(avr, b->twi_vec);
        avr->data[addr] &= ~TWINT;
        if (bus.owner == b->index) {
            bus.owner = -1;
            bus.op = OP_NONE;
        }
        if (bus.slave == b->index) {
            bus.slave = -1;
        }
        if (bus.stretch == b->index) {
            bus.stretch = -1;
        }
        return;
    }
    if (!(v & TWINT)) {
        return;    /* writing 0 to TWINT leaves it as it is */
    }
    avr_clear_interrupt(avr, b->twi_vec);
    avr->data[addr] &= ~TWINT;
    if (bus.stretch == b->index) {
        bus.stretch = -1;   /* the slave lets SCL go */
    }
    if (bus.slave == b->index || (bus.owner != b->index && !(v & (TWSTA | TWSTO)))) {
        return;
    }
    if (v & TWSTA) {
        bus.op = OP_START;
    } else if (v & TWSTO) {
        bus.op = OP_STOP;
    } else if (bus.owner == b->index) {
        if (!b->twi.addressed) {
            bus.op = OP_ADDR;
            bus.byte = avr->data[R_TWDR];
        } else if (bus.reading) {
            bus.op = OP_READ;
            bus.op_ack = (v & TWEA) != 0;
        } else {
            bus.op = OP_WRITE;
            bus.byte = avr->data[R_TWDR];
        }
    } else {
        return;
    }
    bus.op_master = b->index;
    bus.running = 0;
}

static void twsr_write(avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param)
{
    (void)param;
    avr->data[addr] = (avr->data[addr] & 0xF8) | (v & 0x03);   /* only TWPS is writable */
}

void twi_attach(board_t *b)
{
    avr_t *avr = b->avr;
    b->twi_vec = avr->interrupts.vector[TWI_VECTOR];
    b->twi_vec->raise_sticky = 1;    /* TWINT is cleared by software only */
    avr->io[AVR_DATA_TO_IO(R_TWCR)].w.c = twcr_write;
    avr->io[AVR_DATA_TO_IO(R_TWCR)].w.param = b;
    avr->io[AVR_DATA_TO_IO(R_TWSR)].w.c = twsr_write;
    avr->io[AVR_DATA_TO_IO(R_TWSR)].w.param = b;
    avr->io[AVR_DATA_TO_IO(R_TWCR)].r.c = NULL;
    avr->io[AVR_DATA_TO_IO(R_TWDR)].r.c = NULL;
    avr->io[AVR_DATA_TO_IO(R_TWDR)].w.c = NULL;
    avr->io[AVR_DATA_TO_IO(R_TWSR)].r.c = NULL;
    twi_reset(b);
}

/* Power-up or power cut of a board: its TWI is idle, it lets go of the bus. */
void twi_reset(board_t *b)
{
    avr_t *avr = b->avr;
    avr->data[R_TWCR] = 0;
    avr->data[R_TWSR] = 0xF8;
    avr->data[R_TWDR] = 0xFF;
    avr->data[R_TWAR] = 0xFE;
    avr->data[R_TWBR] = 0;
    b->twi.addressed = 0;
    if (bus.owner == b->index) {
        bus.owner = -1;
        bus.op = OP_NONE;
    }
    if (bus.slave == b->index) {
        bus.slave = -1;
    }
    if (bus.stretch == b->index) {
        bus.stretch = -1;
    }
}

static uint64_t bit_cycles(board_t *m)
{
    uint8_t ps = m->avr->data[R_TWSR] & 0x03;
    return 16u + 2u * m->avr->data[R_TWBR] * (1u << (2 * ps));
}

static int find_slave(int master, uint8_t sla)
{
    for (int i = 0; i < N_BOARDS; i++) {
        board_t *s = &H.boards[i];
        uint8_t twcr = s->avr->data[R_TWCR];
        if (i != master && s->powered && H.now >= s->boot_at && (twcr & TWEN) && (twcr & TWEA)
            && (s->avr->data[R_TWAR] >> 1) == (sla >> 1)) {
            return i;
        }
    }
    return -1;
}

static void complete(board_t *m)
{
    board_t *s = bus.slave >= 0 ? &H.boards[bus.slave] : NULL;
    switch (bus.op) {
    case OP_START:
        if (s && !bus.reading) {          /* repeated START ends a write to the slave */
            set_status(s, 0xA0);
            bus.stretch = s->index;
        }
        set_status(m, bus.owner == m->index ? 0x10 : 0x08);
        if (bus.owner != m->index) {
            H.i2c_start_at = bus.due;
        }
        bus.owner = m->index;
        bus.slave = -1;
        m->twi.addressed = 0;
        break;
    case OP_ADDR: {
        bus.reading = bus.byte & 1;
        int si = find_slave(m->index, bus.byte);
        m->twi.addressed = 1;
        if (si >= 0) {
            bus.slave = si;
            set_status(&H.boards[si], bus.reading ? 0xA8 : 0x60);
            bus.stretch = si;
            set_status(m, bus.reading ? 0x40 : 0x18);
        } else {
            H.i2c_naks++;
            set_status(m, bus.reading ? 0x48 : 0x20);
        }
        break;
    }
    case OP_WRITE:
        if (s) {
            int ack = (s->avr->data[R_TWCR] & TWEA) != 0;
            s->avr->data[R_TWDR] = bus.byte;
            set_status(s, ack ? 0x80 : 0x88);
            bus.stretch = s->index;
            set_status(m, ack ? 0x28 : 0x30);
        } else {
            set_status(m, 0x30);
        }
        break;
    case OP_READ:
        m->avr->data[R_TWDR] = s ? s->avr->data[R_TWDR] : 0xFF;
        if (s) {
            set_status(s, bus.op_ack ? 0xB8 : 0xC0);
            bus.stretch = s->index;
        }
        set_status(m, bus.op_ack ? 0x50 : 0x58);
        break;
    case OP_STOP:
        m->avr->data[R_TWCR] &= ~TWSTO;
        if (s && !bus.reading) {
            set_status(s, 0xA0);
            bus.stretch = s->index;
        }
        if (bus.owner == m->index) {
            uint64_t t = bus.due - H.i2c_start_at;
            H.i2c_transactions++;
            H.i2c_sum += t;
            if (t > H.i2c_max) {
                H.i2c_max = t;
            }
            if (H.i2c_min == 0 || t < H.i2c_min) {
                H.i2c_min = t;
            }
        }
        bus.owner = -1;
        bus.slave = -1;
        break;
    default:
        break;
    }
    bus.op = OP_NONE;
    bus.running = 0;
}

/* Start the master's requested operation when the bus lets it, complete it when its bits are
 * on the wire. */
void twi_service(uint64_t now)
{
    if (bus.op == OP_NONE) {
        return;
    }
    board_t *m = &H.boards[bus.op_master];
    if (!m->powered) {
        bus.op = OP_NONE;
        return;
    }
    if (!bus.running) {
        if (bus.stretch >= 0) {
            return;
        }
        if (bus.op == OP_START && bus.owner >= 0 && bus.owner != m->index) {
            return;
        }
        uint64_t bits = (bus.op == OP_START || bus.op == OP_STOP) ? 1 : 9;
        bus.due = now + bits * bit_cycles(m);
        bus.running = 1;
    }
    if (now >= bus.due) {
        complete(m);
    }
}
