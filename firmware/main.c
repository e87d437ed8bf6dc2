/* Entry point: the joint's control (joint.c) plus the board's role (master.c or slave.c). */
#include <avr/interrupt.h>

#include "firmware.h"

struct fw_stats fw_stats;

int main(void)
{
    joint_init();
    role_setup();
    sei();
    for (;;) {
        role_loop();
    }
}
