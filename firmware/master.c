/* Algorithm 1 (joint 1, the I2C master): receive the last complete command from the UART
 * (polling: the loop never waits for one, docs/emulator.md), write each slave's reference, take
 * its own, read the slaves' positions, reply with all four. Frames are those of §5.3
 * (docs/protocol.md); the I2C traffic is that of docs/i2c.md, every loop. */
#if JOINT == 1
#include <avr/interrupt.h>
#include <avr/sleep.h>
#include <util/atomic.h>
#include <util/twi.h>

#include "firmware.h"

#define RX_SIZE 64   /* the Arduino core's serial buffers */
#define TX_SIZE 64
#define CMD_LEN 35   /* between '$' and '#' */

static volatile uint8_t rx_buf[RX_SIZE];
static volatile uint8_t rx_head, rx_tail;
static volatile uint8_t tx_buf[TX_SIZE];
static volatile uint8_t tx_head, tx_tail;

static const uint8_t slave_address[3] = {0x10, 0x11, 0x12};

ISR(USART_RX_vect)
{
    uint8_t c = UDR0;
    uint8_t next = (rx_head + 1) % RX_SIZE;
    if (next == rx_tail) {
        fw_stats.rx_overflows++;   /* full: the new byte is dropped, as the Arduino core does */
    } else {
        rx_buf[rx_head] = c;
        rx_head = next;
    }
}

ISR(USART_UDRE_vect)
{
    if (tx_head == tx_tail) {
        UCSR0B &= ~(1 << UDRIE0);
    } else {
        UDR0 = tx_buf[tx_tail];
        tx_tail = (tx_tail + 1) % TX_SIZE;
    }
}

static void uart_put(uint8_t c)
{
    uint8_t next = (tx_head + 1) % TX_SIZE;
    while (next == tx_tail) {
        /* a print longer than the free buffer blocks, as Serial.print does */
    }
    tx_buf[tx_head] = c;
    tx_head = next;
    UCSR0B |= 1 << UDRIE0;
}

/* The command framer: the last valid "$PPPPP,VV,...#" wins; anything else is counted. */
static uint8_t frame[CMD_LEN + 1];
static uint8_t frame_len;
static uint8_t in_frame;
static uint16_t cmd_ticks[4];
static uint8_t cmd_duty[4];

static uint8_t parse_frame(void)
{
    uint16_t ticks[4];
    uint8_t duties[4];
    if (frame_len != CMD_LEN) {
        return 0;
    }
    for (uint8_t j = 0; j < 4; j++) {
        const uint8_t *f = frame + 9 * j;
        uint32_t t = 0;   /* five digits reach 99 999: 16 bits would wrap (99 999 -> 34 463) */
        for (uint8_t i = 0; i < 5; i++) {
            if (f[i] < '0' || f[i] > '9') {
                return 0;
            }
            t = t * 10 + (f[i] - '0');
        }
        if (f[5] != ',' || f[6] < '0' || f[6] > '9' || f[7] < '0' || f[7] > '9'
            || (j < 3 && f[8] != ',') || t > MAX_TICKS) {
            return 0;
        }
        ticks[j] = (uint16_t)t;
        duties[j] = (f[6] - '0') * 10 + (f[7] - '0');
    }
    for (uint8_t j = 0; j < 4; j++) {
        cmd_ticks[j] = ticks[j];
        cmd_duty[j] = duties[j];
    }
    return 1;
}

/* Feed the bytes received so far; 1 if a new valid command came in. */
static uint8_t uart_poll(void)
{
    uint8_t got = 0;
    while (rx_tail != rx_head) {
        uint8_t c = rx_buf[rx_tail];
        rx_tail = (rx_tail + 1) % RX_SIZE;
        if (c == '$') {
            if (in_frame) {
                fw_stats.bad_frames++;   /* cut short by a new '$' */
            }
            in_frame = 1;
            frame_len = 0;
        } else if (!in_frame) {
            if (c != '\r' && c != '\n') {
                fw_stats.bad_frames++;
            }
        } else if (c == '#') {
            in_frame = 0;
            if (parse_frame()) {
                got = 1;
                fw_stats.commands++;
            } else {
                fw_stats.bad_frames++;
            }
        } else if (frame_len < CMD_LEN + 1) {
            frame[frame_len++] = c;
        } else {
            in_frame = 0;
            fw_stats.bad_frames++;
        }
    }
    return got;
}

/* TWI master. The CPU sleeps (idle) while a byte is on the wire: the TWI interrupt wakes it and
 * masks itself (TWINT stays set for the code to see); the 80 us control interrupt wakes it too.
 * Returns 0 on a NAK, a bus error or a timeout (20 ms without TWINT). */
#define TWI_GO(extra) (TWCR = (1 << TWINT) | (1 << TWEN) | (1 << TWIE) | (extra))
#define TWI_TIMEOUT_WAKEUPS 250

ISR(TWI_vect)
{
    TWCR = TWCR & ~((1 << TWIE) | (1 << TWINT));   /* writing 0 to TWINT leaves it set */
}

static uint8_t twi_wait(void)
{
    uint8_t n = 0;
    cli();
    while (!(TWCR & (1 << TWINT))) {
        if (++n == TWI_TIMEOUT_WAKEUPS) {
            sei();
            return 0;
        }
        sleep_enable();
        sei();
        sleep_cpu();
        sleep_disable();
        cli();
    }
    sei();
    return 1;
}

static void twi_stop(void)
{
    TWCR = (1 << TWINT) | (1 << TWSTO) | (1 << TWEN);
    uint16_t n = 0;
    while ((TWCR & (1 << TWSTO)) && ++n) {
    }
}

static uint8_t twi_start(uint8_t sla)
{
    TWI_GO(1 << TWSTA);
    if (!twi_wait() || (TW_STATUS != TW_START && TW_STATUS != TW_REP_START)) {
        return 0;
    }
    TWDR = sla;
    TWI_GO(0);
    if (!twi_wait()) {
        return 0;
    }
    return TW_STATUS == TW_MT_SLA_ACK || TW_STATUS == TW_MR_SLA_ACK;
}

static uint8_t i2c_write(uint8_t addr, const uint8_t *data, uint8_t n)
{
    uint8_t ok = twi_start(addr << 1);
    for (uint8_t i = 0; ok && i < n; i++) {
        TWDR = data[i];
        TWI_GO(0);
        ok = twi_wait() && TW_STATUS == TW_MT_DATA_ACK;
    }
    twi_stop();
    return ok;
}

static uint8_t i2c_read(uint8_t addr, uint8_t *data, uint8_t n)
{
    uint8_t ok = twi_start(addr << 1 | 1);
    for (uint8_t i = 0; ok && i < n; i++) {
        TWI_GO(i + 1 < n ? 1 << TWEA : 0);
        ok = twi_wait();
        data[i] = TWDR;
    }
    twi_stop();
    return ok;
}

static void put_ticks(uint16_t t)
{
    char d[5];
    for (int8_t i = 4; i >= 0; i--) {
        d[i] = '0' + t % 10;
        t /= 10;
    }
    for (uint8_t i = 0; i < 5; i++) {
        uart_put(d[i]);
    }
}

static uint16_t positions[3];

void role_setup(void)
{
    UCSR0A = 1 << U2X0;
    UBRR0 = (F_CPU / 8 / UART_BAUD) - 1;   /* 16: 117 647 baud, as the Arduino core sets it */
    UCSR0B = (1 << RXEN0) | (1 << TXEN0) | (1 << RXCIE0);
    UCSR0C = (1 << UCSZ01) | (1 << UCSZ00);
    TWSR = 0;
    TWBR = (F_CPU / I2C_HZ - 16) / 2;
    TWCR = 1 << TWEN;
    set_sleep_mode(SLEEP_MODE_IDLE);
    sei();
    while (joint_recovering()) {   /* §5.2: the master's loop starts once its joint is homed */
        joint_store_motion();
    }
}

void role_eeprom_busy(void)
{
    /* Algorithm 1 waits: its own position was read before the record, the reply follows it */
}

void role_loop(void)
{
    uint8_t ref[4];
    /* Receive reference poses and velocities from UART */
    uint8_t fresh = uart_poll();
    /* Update reference pose and velocity of joints 2..4 through I2C (every loop) */
    for (uint8_t k = 0; k < 3; k++) {
        ref[0] = REG_REFERENCE;
        ref[1] = cmd_ticks[k + 1] & 0xFF;
        ref[2] = cmd_ticks[k + 1] >> 8;
        ref[3] = cmd_duty[k + 1];
        if (!i2c_write(slave_address[k], ref, 4)) {
            fw_stats.i2c_errors++;
        }
    }
    /* Update reference pose of joint 1 */
    if (fresh) {
        joint_set_reference(cmd_ticks[0], cmd_duty[0]);
    }
    /* Request current pose of joints 2..4 through I2C */
    for (uint8_t k = 0; k < 3; k++) {
        uint8_t b[2];
        if (i2c_read(slave_address[k], b, 2)) {
            positions[k] = b[0] | (uint16_t)b[1] << 8;
        } else {
            fw_stats.i2c_errors++;   /* keep the last known position */
        }
    }
    /* Update current pose of joint 1 */
    uint16_t own = joint_position_ticks();
    joint_store_motion();
    /* Pack all current poses and send through UART */
    uart_put('$');
    put_ticks(own);
    for (uint8_t k = 0; k < 3; k++) {
        uart_put(',');
        put_ticks(positions[k]);
    }
    uart_put('#');
    fw_stats.loops++;
}
#endif
