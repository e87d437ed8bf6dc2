/* The harness's outside: joint 1's UART on a pty (host bytes queued for the UART, reply bytes
 * buffered and written a frame at a time) and the control commands on stdin or a FIFO.
 *
 * Commands, one per line: "power off", "power on" (all four boards), "eeprom blank" (every
 * board's EEPROM erased, as a programmer would; unpowered only), "home" (every joint turned back
 * to its zero position, as an operator re-homing the arm by hand; unpowered only), "stats"
 * (prints "stats {json}"), "quit". "eeprom blank" then "home" re-reference an arm whose start-up
 * recovery stalled: at power-up the firmware finds no record and counts from zero where the joints
 * stand. */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <termios.h>
#include <unistd.h>

#include "harness.h"

static uint8_t tx_buf[4096];
static size_t tx_len;

/* Write the buffered reply bytes to the pty; what the pty cannot take (nobody reading and its
 * buffer full) is lost, as on an unread line. */
void pty_flush(void)
{
    if (H.pty_fd >= 0 && tx_len) {
        ssize_t n = write(H.pty_fd, tx_buf, tx_len);
        if (n < (ssize_t)tx_len) {
            H.tx_lost += tx_len - (n > 0 ? (size_t)n : 0);
        }
    }
    tx_len = 0;
}

/* One byte from joint 1's UART for the pty: written at the end of a reply frame ('#') or when
 * the harness polls its inputs (every simulated millisecond), not one system call per byte. */
void pty_put(uint8_t c)
{
    if (H.pty_fd < 0) {
        return;
    }
    if (tx_len == sizeof tx_buf) {
        pty_flush();
    }
    tx_buf[tx_len++] = c;
    if (c == '#') {
        pty_flush();
    }
}

/* Cut or restore the power of all four boards ("power off", "power on", a script's @power). */
void power_all(int on)
{
    for (int i = 0; i < N_BOARDS; i++) {
        if (on && !H.boards[i].powered) {
            board_power_on(&H.boards[i]);
        } else if (!on && H.boards[i].powered) {
            board_power_off(&H.boards[i]);
        }
    }
    watch_power(on);
}

static int all_unpowered(const char *command)
{
    for (int i = 0; i < N_BOARDS; i++) {
        if (H.boards[i].powered) {
            fprintf(stderr, "armfw-harness: %s: refused while the boards are powered\n", command);
            return 0;
        }
    }
    return 1;
}

/* One command line (the table above); 0 for "quit". */
int harness_command(const char *line, double wall_s)
{
    if (strncmp(line, "power off", 9) == 0) {
        power_all(0);
    } else if (strncmp(line, "power on", 8) == 0) {
        power_all(1);
    } else if (strncmp(line, "eeprom blank", 12) == 0) {
        if (all_unpowered("eeprom blank")) {
            for (int i = 0; i < N_BOARDS; i++) {
                board_eeprom_blank(&H.boards[i]);
            }
        }
    } else if (strncmp(line, "home", 4) == 0) {
        if (all_unpowered("home")) {
            for (int i = 0; i < N_BOARDS; i++) {
                joint_home(&H.boards[i]);
            }
        }
    } else if (strncmp(line, "stats", 5) == 0) {
        print_stats(wall_s);
    } else if (strncmp(line, "quit", 4) == 0) {
        return 0;
    } else {
        fprintf(stderr, "armfw-harness: unknown command: %s\n", line);
    }
    return 1;
}

typedef struct line_reader_t {
    int fd;
    char line[256];
    size_t len;
} line_reader_t;

static line_reader_t control_in = {0, {0}, 0}, control_fifo = {-1, {0}, 0};

void open_control_fifo(const char *path)
{
    control_fifo.fd = open(path, O_RDWR | O_NONBLOCK);   /* RDWR: no EOF churn */
    if (control_fifo.fd < 0) {
        die("cannot open the control FIFO", path);
    }
}

/* Run the complete command lines readable on `r`; 0 when told to quit or, for stdin, when the
 * parent closed it (no orphan harness) unless the run has a --seconds limit. */
static int read_commands(line_reader_t *r, double wall_s)
{
    char buf[256];
    ssize_t n = read(r->fd, buf, sizeof buf);
    if (n == 0 && r == &control_in && H.stop_after_s < 0) {
        return 0;
    }
    for (ssize_t i = 0; i < n; i++) {
        if (buf[i] == '\n' || r->len == sizeof r->line - 1) {
            r->line[r->len] = 0;
            r->len = 0;
            if (!harness_command(r->line, wall_s)) {
                return 0;
            }
        } else {
            r->line[r->len++] = buf[i];
        }
    }
    return 1;
}

/* Flush the replies, read the pty and the control inputs without blocking; 0 when told to
 * quit. */
int poll_io(double wall_s)
{
    pty_flush();
    fd_set fds;
    FD_ZERO(&fds);
    FD_SET(0, &fds);
    int top = 0;
    if (H.pty_fd >= 0) {
        FD_SET(H.pty_fd, &fds);
        top = H.pty_fd > top ? H.pty_fd : top;
    }
    if (control_fifo.fd >= 0) {
        FD_SET(control_fifo.fd, &fds);
        top = control_fifo.fd > top ? control_fifo.fd : top;
    }
    struct timeval tv = {0, 0};
    if (select(top + 1, &fds, NULL, NULL, &tv) <= 0) {
        return 1;
    }
    if (H.pty_fd >= 0 && FD_ISSET(H.pty_fd, &fds)) {
        uint8_t buf[512];
        ssize_t n = read(H.pty_fd, buf, sizeof buf);
        if (n > 0) {
            uart_queue(buf, (size_t)n);
        }
    }
    if (control_fifo.fd >= 0 && FD_ISSET(control_fifo.fd, &fds)
        && !read_commands(&control_fifo, wall_s)) {
        return 0;
    }
    return !FD_ISSET(0, &fds) || read_commands(&control_in, wall_s);
}

void open_pty(void)
{
    H.pty_fd = posix_openpt(O_RDWR | O_NOCTTY);
    if (H.pty_fd < 0 || grantpt(H.pty_fd) || unlockpt(H.pty_fd)) {
        die("cannot open a pty", strerror(errno));
    }
    const char *name = ptsname(H.pty_fd);
    int slave = open(name, O_RDWR | O_NOCTTY);   /* kept open: a client may close and reopen */
    struct termios t;
    tcgetattr(slave, &t);
    cfmakeraw(&t);
    tcsetattr(slave, TCSANOW, &t);
    fcntl(H.pty_fd, F_SETFL, O_NONBLOCK);
    printf("pty %s\n", name);
    fflush(stdout);
}
