/* Algorithm 2 (joints 2..4): answer the master on I2C with the register layout of docs/i2c.md.
 * The TWI interrupt takes the bytes; the main loop applies a new reference (held while the
 * start-up recovery runs; also while it waits for the EEPROM), stores motion changes in the EEPROM, keeps the position register
 * current and sleeps otherwise. The TWI interrupt is kept short (no arithmetic): while it runs
 * the encoder's A-edge interrupt waits, and channel B must still hold its level when it runs. */
#if JOINT != 1
#include <avr/interrupt.h>
#include <avr/sleep.h>
#include <util/twi.h>

#include "firmware.h"

static volatile uint8_t rx_buf[4];
static volatile uint8_t rx_len;
static volatile uint8_t pointer = REG_POSITION;
static volatile uint8_t tx_buf[2];
static volatile uint8_t tx_len, tx_pos;
static volatile uint16_t ref_ticks;
static volatile uint8_t ref_duty;
static volatile uint8_t ref_pending;
static volatile uint16_t pos_ticks;   /* the counter in wire ticks, refreshed by the main loop
                                         after every interrupt: the TWI ISR only copies it */

static void take_write(void)
{
    uint8_t n = rx_len;
    if (n == 0) {
        return;
    }
    uint8_t reg = rx_buf[0];
    if (reg == REG_REFERENCE && n == 4) {
        uint16_t ticks = rx_buf[1] | (uint16_t)rx_buf[2] << 8;
        if (ticks > MAX_TICKS || rx_buf[3] > 99) {
            fw_stats.bad_writes++;
        } else {
            ref_ticks = ticks;
            ref_duty = rx_buf[3];
            ref_pending = 1;
        }
        pointer = REG_POSITION;
    } else if (n == 1 && (reg == REG_POSITION || reg == REG_STATUS || reg == REG_WHO_AM_I)) {
        pointer = reg;
    } else {
        fw_stats.bad_writes++;
    }
    rx_len = 0;
}

ISR(TWI_vect)
{
    switch (TW_STATUS) {
    case TW_SR_SLA_ACK:
        rx_len = 0;
        break;
    case TW_SR_DATA_ACK:
        if (rx_len < sizeof rx_buf) {
            rx_buf[rx_len] = TWDR;
        }
        if (rx_len < 255) {
            rx_len++;
        }
        break;
    case TW_SR_STOP:
        take_write();
        break;
    case TW_ST_SLA_ACK:
        take_write();   /* a repeated START ends a write without a STOP */
        if (pointer == REG_STATUS) {
            tx_buf[0] = joint_status();
            tx_len = 1;
        } else if (pointer == REG_WHO_AM_I) {
            tx_buf[0] = 0xA0 | JOINT;
            tx_len = 1;
        } else {
            uint16_t t = pos_ticks;
            tx_buf[0] = t & 0xFF;
            tx_buf[1] = t >> 8;
            tx_len = 2;
        }
        pointer = REG_POSITION;
        tx_pos = 0;
        TWDR = tx_buf[tx_pos++];
        break;
    case TW_ST_DATA_ACK:
        TWDR = tx_pos < tx_len ? tx_buf[tx_pos++] : 0xFF;
        break;
    case TW_BUS_ERROR:
        TWCR = (1 << TWSTO) | (1 << TWINT) | (1 << TWEN) | (1 << TWEA) | (1 << TWIE);
        return;
    default:   /* TW_ST_DATA_NACK, TW_ST_LAST_DATA: the read is over */
        break;
    }
    TWCR = (1 << TWINT) | (1 << TWEN) | (1 << TWEA) | (1 << TWIE);
}

void role_setup(void)
{
    TWAR = I2C_ADDRESS << 1;
    TWCR = (1 << TWEN) | (1 << TWEA) | (1 << TWIE);
    set_sleep_mode(SLEEP_MODE_IDLE);
}

/* The POSITION register kept current: the conversion only when the counter moved. */
static void refresh_position(void)
{
    static int32_t last = -1;
    int32_t c;
    cli();
    c = joint_counter;
    sei();
    if (c != last) {
        uint16_t t = joint_position_ticks();
        last = c;
        cli();
        pos_ticks = t;
        sei();
    }
}

/* A reference the TWI interrupt took, applied (held while the start-up recovery runs). */
static void take_reference(void)
{
    if (ref_pending && !joint_recovering()) {
        uint16_t ticks;
        uint8_t d;
        cli();
        ticks = ref_ticks;
        d = ref_duty;
        ref_pending = 0;
        sei();
        joint_set_reference(ticks, d);
    }
}

/* While the joint's EEPROM record is written (up to 13 ms) the master still reads the position
 * and writes references: keep the position current and take a new reference at once (Wire's
 * onReceive runs in the interrupt, Algorithm 2 takes it there), or a moving joint reports a stale
 * position and a new command waits for the record. */
void role_eeprom_busy(void)
{
    refresh_position();
    take_reference();
}

void role_loop(void)
{
    refresh_position();
    cli();
    if (!ref_pending || joint_recovering()) {
        sleep_enable();
        sei();
        sleep_cpu();
        sleep_disable();
    }
    sei();
    take_reference();
    joint_store_motion();
}
#endif
