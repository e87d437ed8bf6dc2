/* One joint's mechanics seen by its board's pins: the TB6600 takes a microstep on each rising
 * edge of STEP in the direction DIR gives (high = CW); the motor-shaft encoder (counts_num /
 * counts_den counts per microstep, 5/4 by default) answers with a full A/B quadrature cycle per
 * count, its four edges ENCODER_EDGE_CYCLES apart after the step; the Hall sensor N goes high
 * when the motor stands on hall_step, after the step's encoder edges. A step past a hard limit
 * does not move the shaft (stall). */
#include <simavr/avr_ioport.h>

#include "harness.h"

#define ENCODER_EDGE_CYCLES 256u   /* 16 us between the edges of one step's counts */
#define PIN_A 2
#define PIN_HALL 3
#define PIN_B 4
#define PIN_STEP 5
#define PIN_DIR 6
#define EICRA_ADDR 0x69

static const uint8_t gray_a[4] = {0, 0, 1, 1};
static const uint8_t gray_b[4] = {0, 1, 1, 0};

static int64_t floor_div(int64_t a, int64_t b)
{
    int64_t q = a / b;
    return (a % b != 0 && ((a < 0) != (b < 0))) ? q - 1 : q;
}

static void push(joint_t *j, uint64_t at, uint8_t pin, uint8_t level)
{
    unsigned next = (j->q_tail + 1) % PIN_QUEUE;
    if (next == j->q_head) {
        return;   /* a step faster than its edges can follow: drop (never at duty <= 99) */
    }
    j->queue[j->q_tail] = (pin_event_t){at, pin, level};
    j->q_tail = next;
    j->last_event = at;
}

static void on_step(board_t *b)
{
    joint_t *j = &b->joint;
    int64_t dir = j->dir_level ? 1 : -1;
    int64_t to = j->motor_steps + dir;
    if (to < j->lower_steps || to > j->upper_steps) {
        j->blocked++;
        return;
    }
    int64_t before = floor_div(j->motor_steps * j->counts_num, j->counts_den);
    int64_t after = floor_div(to * j->counts_num, j->counts_den);
    j->motor_steps = to;
    j->steps++;
    uint64_t t = b->avr->cycle > j->last_event ? b->avr->cycle : j->last_event;
    if (j->hall_level && to != j->hall_step) {
        push(j, t, PIN_HALL, 0);
        j->hall_level = 0;
    }
    for (int64_t n = before; n != after; n += dir) {
        for (int e = 0; e < 4; e++) {
            uint8_t g0 = j->gray;
            j->gray = (uint8_t)((j->gray + (dir > 0 ? 1 : 3)) & 3);
            t += ENCODER_EDGE_CYCLES;
            if (gray_a[g0] != gray_a[j->gray]) {
                push(j, t, PIN_A, gray_a[j->gray]);
            } else {
                push(j, t, PIN_B, gray_b[j->gray]);
            }
        }
    }
    if (to == j->hall_step) {
        push(j, t + ENCODER_EDGE_CYCLES, PIN_HALL, 1);
        j->hall_level = 1;
    }
}

static void step_changed(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    board_t *b = param;
    uint8_t rising = value && !b->joint.step_level;
    b->joint.step_level = value != 0;
    if (rising && b->powered) {
        on_step(b);
    }
}

static void dir_changed(struct avr_irq_t *irq, uint32_t value, void *param)
{
    (void)irq;
    board_t *b = param;
    b->joint.dir_level = value != 0;
}

void joint_attach(board_t *b)
{
    avr_t *avr = b->avr;
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), PIN_STEP),
                            step_changed, b);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), PIN_DIR),
                            dir_changed, b);
    joint_t *j = &b->joint;
    j->q_head = j->q_tail = 0;
    j->gray = 0;
    j->hall_level = j->motor_steps == j->hall_step;
    /* simavr 1.6 starts polling a pin for INT0/INT1's low-level mode (EICRA = 0 at reset) when it
     * is driven low and never stops while it stays low: a timer call every cycle. The pins are
     * driven here with EICRA set to edge modes for the moment; the firmware sets its own. */
    uint8_t eicra = avr->data[EICRA_ADDR];
    avr->data[EICRA_ADDR] = 0x0F;
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), PIN_A), 0);
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), PIN_B), 0);
    avr_raise_irq(avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), PIN_HALL), j->hall_level);
    avr->data[EICRA_ADDR] = eicra;
}

/* Drive the pins whose change is due by the board's cycle. */
void joint_service(board_t *b, uint64_t now)
{
    joint_t *j = &b->joint;
    while (j->q_head != j->q_tail && j->queue[j->q_head].at <= now) {
        pin_event_t *e = &j->queue[j->q_head];
        avr_raise_irq(avr_io_getirq(b->avr, AVR_IOCTL_IOPORT_GETIRQ('D'), e->pin), e->level);
        j->q_head = (j->q_head + 1) % PIN_QUEUE;
    }
}

/* "home" while unpowered: the joint turned back to its zero position (microstep 0, the zero
 * pose), as an operator re-homing the arm by hand would; the pins follow at the next power-up. */
void joint_home(board_t *b)
{
    b->joint.motor_steps = 0;
    b->joint.q_head = b->joint.q_tail = 0;
}
