/* The reference firmware's shared declarations: one source tree, the role and the joint chosen
 * at build time with -DJOINT=1 (master, Algorithm 1) or 2..4 (slaves, Algorithm 2). */
#ifndef ARMFW_FIRMWARE_H
#define ARMFW_FIRMWARE_H

#include <stdint.h>

#include "joints.h"
#include "pins.h"

#define MOTION_STOPPED 0
#define MOTION_CW 1
#define MOTION_CCW 2

/* I2C registers of a slave (docs/i2c.md) */
#define REG_REFERENCE 0x01
#define REG_POSITION 0x02
#define REG_STATUS 0x03
#define REG_WHO_AM_I 0x04
#define MAX_TICKS 62832U

/* Counters a harness or debugger can read (symbol fw_stats, little-endian fields). */
struct fw_stats {
    uint32_t loops;          /* master main loops (replies sent) */
    uint16_t rx_overflows;   /* bytes dropped: the 64-byte receive buffer was full */
    uint16_t bad_frames;     /* '$'...'#' runs that were not a valid command */
    uint16_t i2c_errors;     /* master: NAKs and bus errors */
    uint16_t bad_writes;     /* slave: malformed or out-of-range I2C writes */
    uint16_t commands;       /* master: valid commands taken */
};
extern struct fw_stats fw_stats;

extern volatile int32_t joint_counter;

void joint_init(void);
void joint_store_motion(void);
uint8_t joint_recovering(void);
void joint_set_reference(uint16_t ticks, uint8_t duty);
uint16_t joint_position_ticks(void);
uint8_t joint_status(void);

void role_setup(void);
void role_loop(void);
void role_eeprom_busy(void);   /* called while a record store waits for the EEPROM */

#endif
