/* Every pin of the reference firmware, one place (Arduino Pro Mini, ATmega328P @ 16 MHz, 5 V).
 *
 * A lab's own firmware runs in the harness (firmware/harness/) when it uses these pins:
 *
 *   signal        port bit  Arduino pin  direction  meaning
 *   ------------  --------  -----------  ---------  ------------------------------------------------
 *   ENC_A         PD2       D2 (INT0)    in         encoder channel A: each rising edge is one count
 *   ENC_B         PD4       D4           in         encoder channel B: high at A's rising edge = CW
 *   HALL          PD3       D3 (INT1)    in         Hall sensor N: rising edge = joint at its Hall
 *   STEP          PD5       D5           out        TB6600 PUL+: a rising edge is one microstep
 *   DIR           PD6       D6           out        TB6600 DIR+: high = CW (counter counts up)
 *   ENABLE        PD7       D7           out        TB6600 ENA+: low = driver enabled
 *   RX / TX       PD0/PD1   D0/D1        uart       master only: host link, 115200 8N1
 *   SDA / SCL     PC4/PC5   A4/A5        twi        I2C bus between the four boards (100 kHz)
 *
 * The 80 us control cycle is Timer1 in CTC mode (OCR1A = 1279, no prescaler):
 * TIMER1_COMPA_vect, vector 11, 1280 cycles at 16 MHz.
 */
#ifndef ARMFW_PINS_H
#define ARMFW_PINS_H

#include <avr/io.h>

#define ENC_PORT_IN   PIND
#define ENC_A_BIT     PD2
#define ENC_B_BIT     PD4
#define HALL_BIT      PD3
#define STEP_BIT      PD5
#define DIR_BIT       PD6
#define ENABLE_BIT    PD7
#define MOTOR_PORT    PORTD
#define MOTOR_DDR     DDRD

#define CONTROL_CYCLE_CYCLES 1280u   /* 80 us at 16 MHz */
#define UART_BAUD     115200UL
#define I2C_HZ        100000UL

#endif
