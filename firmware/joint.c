/* One joint's motion control, common to the master and the slaves (paper §5.1, §5.2).
 *
 * - The Fig. 7 PWM state machine runs in the 80 us Timer1 compare interrupt: STOP -> PWM_HIGH when
 *   the duty is positive and the error is beyond the deadband; PWM_HIGH makes one step and goes to
 *   PWM_LOW, or stops inside the deadband (with -DSTOP_RULE_REACH=1: once the counter meets or
 *   passes the target, emulator.stop_rule = "reach"); PWM_LOW counts non_moved_steps up to 100 - duty. A step every 101 - duty cycles:
 *   speed law (12), 1e6 / (80 (101 - v)) steps/s.
 * - The encoder counter follows channel A's rising edge (INT0): B high = CW, +1; else -1.
 * - The Hall sensor's rising edge (INT1) resets the counter to HALL_COUNT, once per arrival.
 * - §5.2: every motion change (stopped / moving CW / moving CCW) is stored in the EEPROM with the
 *   counter; at power-up a "stopped" record restores the counter, a "moving" one drives the joint
 *   the opposite way until the Hall sensor resets it.
 */
#include <avr/eeprom.h>
#include <avr/interrupt.h>
#include <util/atomic.h>

#include "firmware.h"

enum { ST_STOP, ST_PWM_HIGH, ST_PWM_LOW };

volatile int32_t joint_counter;
static volatile int32_t target_counts;
static volatile uint8_t duty;
static volatile uint8_t pwm_state = ST_STOP;
static volatile uint8_t non_moved_steps;
static volatile int8_t home_dir;          /* +1/-1 while recovering, 0 otherwise */
static volatile uint8_t recovery_stalled;
static volatile uint8_t stall_pulses;
static volatile uint8_t motion = MOTION_STOPPED;
static volatile uint8_t motion_dirty;     /* a motion change waits for its EEPROM record */
static volatile int32_t motion_counter;   /* the counter when it changed */
static uint8_t step_high;

/* The EEPROM record, as fakes/eeprom.py: state (0 stopped, 1 CW, 2 CCW, 0xFF blank), int32. */
#define EE_STATE ((uint8_t *)0)
#define EE_COUNTER ((uint32_t *)1)

static void set_motion(uint8_t m)
{
    if (m != motion) {
        motion = m;
        motion_counter = joint_counter;
        motion_dirty = 1;
    }
}

ISR(INT0_vect)   /* encoder A rising edge */
{
    if (ENC_PORT_IN & (1 << ENC_B_BIT)) {
        joint_counter++;
    } else {
        joint_counter--;
    }
    stall_pulses = 0;
}

ISR(INT1_vect)   /* Hall sensor reached */
{
    joint_counter = HALL_COUNT;
    if (home_dir) {
        home_dir = 0;
        target_counts = HALL_COUNT;
    }
}

ISR(TIMER1_COMPA_vect)
{
    if (step_high) {             /* end of the previous cycle's step pulse */
        MOTOR_PORT &= ~(1 << STEP_BIT);
        step_high = 0;
    }
    int32_t err;
    uint8_t v = duty;
    if (home_dir) {
        err = home_dir;
        v = RECOVERY_DUTY;
    } else {
        err = target_counts - joint_counter;
#if STOP_RULE_REACH
        if (pwm_state == ST_PWM_HIGH) {   /* moving: on until the target is met or passed */
            if (motion == MOTION_CW ? err <= 0 : err >= 0) {
                err = 0;
            }
        } else
#endif
        if (err <= DEADBAND_COUNTS && err >= -DEADBAND_COUNTS) {
            err = 0;
        }
    }
    switch (pwm_state) {
    case ST_STOP:
        if (v > 0 && err != 0) {
            pwm_state = ST_PWM_HIGH;
            set_motion(err > 0 ? MOTION_CW : MOTION_CCW);
        }
        break;
    case ST_PWM_HIGH:
        if (v == 0 || err == 0) {
            pwm_state = ST_STOP;
            set_motion(MOTION_STOPPED);
        } else {
            if (err > 0) {
                MOTOR_PORT |= 1 << DIR_BIT;
            } else {
                MOTOR_PORT &= ~(1 << DIR_BIT);
            }
            MOTOR_PORT |= 1 << STEP_BIT;
            step_high = 1;
            set_motion(err > 0 ? MOTION_CW : MOTION_CCW);
            if (home_dir && ++stall_pulses >= RECOVERY_STALL_PULSES) {
                recovery_stalled = 1;
                stall_pulses = RECOVERY_STALL_PULSES;
            }
            pwm_state = ST_PWM_LOW;
            non_moved_steps = 0;
        }
        break;
    default:
        if (++non_moved_steps >= 100 - v) {
            pwm_state = ST_PWM_HIGH;
        }
        break;
    }
}

void joint_init(void)
{
    MOTOR_DDR |= (1 << STEP_BIT) | (1 << DIR_BIT) | (1 << ENABLE_BIT);
    MOTOR_PORT &= ~((1 << STEP_BIT) | (1 << ENABLE_BIT));
    uint8_t state = eeprom_read_byte(EE_STATE);
    int32_t counter = (int32_t)eeprom_read_dword(EE_COUNTER);
    if (state > MOTION_CCW) {          /* blank: a new arm, assembled at its zero pose */
        state = MOTION_STOPPED;
        counter = 0;
    }
    joint_counter = counter;
    target_counts = counter;
    motion = MOTION_STOPPED;
    if (state != MOTION_STOPPED) {     /* §5.2: powered off while moving: find the Hall */
        if (ENC_PORT_IN & (1 << HALL_BIT)) {
            joint_counter = HALL_COUNT;    /* already on it: the level says so */
            target_counts = HALL_COUNT;
        } else {
            home_dir = state == MOTION_CW ? -1 : 1;
        }
    }
    EICRA = (1 << ISC01) | (1 << ISC00) | (1 << ISC11) | (1 << ISC10);  /* rising edges */
    EIFR = (1 << INTF0) | (1 << INTF1);
    EIMSK = (1 << INT0) | (1 << INT1);
    TCCR1A = 0;
    TCCR1B = (1 << WGM12) | (1 << CS10);   /* CTC, clk/1 */
    OCR1A = CONTROL_CYCLE_CYCLES - 1;
    TIMSK1 = 1 << OCIE1A;
}

/* One cell of the record: wait until the EEPROM has finished the previous write (3.3 ms a byte)
 * while the role does what must not wait (a slave keeps its position register current), then
 * read it and write it if it changed. */
static void record_byte(uint8_t *address, uint8_t value)
{
    while (!eeprom_is_ready()) {
        role_eeprom_busy();
    }
    eeprom_update_byte(address, value);
}

void joint_store_motion(void)
{
    uint8_t dirty, m;
    int32_t c;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        dirty = motion_dirty;
        motion_dirty = 0;
        m = motion;
        c = motion_counter;
    }
    if (dirty) {   /* EEPROM.put: only changed cells are written; the state, then the counter
                      from its high byte down (fakes/eeprom.py RECORD_ACCESS_ORDER) */
        record_byte(EE_STATE, m);
        for (int8_t i = 3; i >= 0; i--) {
            record_byte((uint8_t *)EE_COUNTER + i, (uint8_t)((uint32_t)c >> (8 * i)));
        }
    }
}

uint8_t joint_recovering(void)
{
    return home_dir != 0;
}

void joint_set_reference(uint16_t ticks, uint8_t new_duty)
{
    int64_t tq = (int64_t)ticks << 16;
    if (ticks >= WRAP_TICKS) {
        tq -= TAU_TICKS_Q16;
    }
    int64_t prod = tq * COUNTS_PER_TICK_Q24;
    int32_t counts = (int32_t)((prod + ((int64_t)1 << 39)) >> 40);
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        target_counts = counts;
        duty = new_duty;
    }
}

uint16_t joint_position_ticks(void)
{
    /* called from the TWI interrupt, so 16x16->32 multiplies only (a few dozen cycles): with
     * K = TICKS_PER_COUNT_Q31 = Kh * 2^16 + Kl, |c| * K / 2^16 = |c| * Kh + (|c| * Kl) / 2^16
     * (ticks in Q15; the dropped bits are below 2^-15 ticks) */
    int32_t c;
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
        c = joint_counter;
    }
    if (c >= 65536L || c <= -65536L) {
        /* beyond every joint's reach (a record torn by a power cut restored it): the same angle
         * within half a turn of zero; a 32-bit remainder, in this case only */
        c %= COUNTS_PER_TURN;
        if (c > COUNTS_PER_TURN / 2) {
            c -= COUNTS_PER_TURN;
        } else if (c < -COUNTS_PER_TURN / 2) {
            c += COUNTS_PER_TURN;
        }
    }
    uint16_t ac = (uint16_t)(c < 0 ? -c : c);   /* |c| <= COUNTS_PER_TURN / 2 < 2^16 */
    uint32_t q15 = (uint32_t)ac * (uint16_t)(TICKS_PER_COUNT_Q31 >> 16)
        + (((uint32_t)ac * (uint16_t)(TICKS_PER_COUNT_Q31 & 0xFFFF)) >> 16);
    if (c < 0) {
        q15 = TAU_TICKS_Q15 - q15;
    }
    return (uint16_t)((q15 + (1UL << 14)) >> 15);
}

uint8_t joint_status(void)
{
    uint8_t m = motion;
    uint8_t rec = home_dir != 0;
    return (m != MOTION_STOPPED) | (m == MOTION_CW) << 1 | rec << 2
        | (rec && recovery_stalled) << 3 | (!rec) << 4;
}
