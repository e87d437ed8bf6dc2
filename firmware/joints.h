/* Per-joint constants of the reference firmware, for the default robot settings
 * (armbench.drivers.settings: 1.8 deg motors at 8 microsteps, 2000 encoder counts per motor
 * revolution, gears 50/50/38/28, Hall at 0 rad). tests/test_firmware.py recomputes every value
 * from the settings and fails if one differs.
 *
 * Wire ticks <-> encoder counts are done in integers (no float on the AVR):
 *   counts -> ticks: floor(((counts / cpr) mod 2pi) * 1e4 + 0.5)
 *                    = ([TAU_TICKS_Q15 -] |counts| * TICKS_PER_COUNT_Q31 / 2^16 + 2^14) >> 15
 *   ticks -> counts: round((ticks / 1e4 - (ticks >= WRAP_TICKS ? 2pi : 0)) * cpr)
 *                    = round(((ticks << 16) - [TAU_TICKS_Q16]) * COUNTS_PER_TICK_Q24 / 2^40)
 * cpr = counts per joint radian; WRAP_TICKS is the first wire value decoded as a negative angle
 * (the window centred on the joint's limits, docs/protocol.md); COUNTS_PER_TURN = 2 pi cpr, the
 * counts of one joint turn (a whole number: encoder counts per motor revolution x gear).
 */
#ifndef ARMFW_JOINTS_H
#define ARMFW_JOINTS_H

#ifndef JOINT
#error "build with -DJOINT=1..4 (1 = master)"
#endif

#define TAU_TICKS_Q16 4117748323LL        /* 2pi * 1e4 * 2^16 */
#define TAU_TICKS_Q15 2058874161UL        /* 2pi * 1e4 * 2^15 */

#if JOINT == 1
#define TICKS_PER_COUNT_Q31 1349303770UL
#define COUNTS_PER_TICK_Q24 26701769L
#define WRAP_TICKS 31416U
#define COUNTS_PER_TURN 100000L
#define HALL_COUNT 0L
#elif JOINT == 2
#define TICKS_PER_COUNT_Q31 1349303770UL
#define COUNTS_PER_TICK_Q24 26701769L
#define WRAP_TICKS 33598U
#define COUNTS_PER_TURN 100000L
#define HALL_COUNT 0L
#define I2C_ADDRESS 0x10
#elif JOINT == 3
#define TICKS_PER_COUNT_Q31 1775399698UL
#define COUNTS_PER_TICK_Q24 20293344L
#define WRAP_TICKS 28798U
#define COUNTS_PER_TURN 76000L
#define HALL_COUNT 0L
#define I2C_ADDRESS 0x11
#elif JOINT == 4
#define TICKS_PER_COUNT_Q31 2409471019UL
#define COUNTS_PER_TICK_Q24 14952990L
#define WRAP_TICKS 39270U
#define COUNTS_PER_TURN 56000L
#define HALL_COUNT 0L
#define I2C_ADDRESS 0x12
#else
#error "JOINT must be 1..4"
#endif

#ifndef DEADBAND_COUNTS
#define DEADBAND_COUNTS 1       /* |target - counter| <= 1 count: there (docs/emulator.md) */
#endif
#ifndef STOP_RULE_REACH
#define STOP_RULE_REACH 0       /* 1: a moving joint stops once it meets or passes its target */
#endif
#define RECOVERY_DUTY 90        /* drive to the Hall sensor at start-up (§5.2) */
#define RECOVERY_STALL_PULSES 64 /* pulses without a count while recovering: stalled at a limit */

#endif
