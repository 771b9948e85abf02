/*
 * The reference firmware served on a pseudo-terminal in real time: the host build behind
 * `hil sim-serve board --impl c` and `sim://board?impl=c`. Prints the pty path on the first
 * line of stdout (open it like a serial port), then serves until SIGINT or SIGTERM.
 * The analog world is a loopback cable (--delay samples, --gain linear).
 */
#define _XOPEN_SOURCE 600
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "../casfw.h"
#include "../casfw_loopback.h"

static casfw_board board;
static casfw_loopback world;
static struct timespec t0;
static volatile sig_atomic_t stopping;

static casfw_ns real_now(void *ctx) {
    (void)ctx;
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (casfw_ns)(t.tv_sec - t0.tv_sec) * 1000000000ull + (casfw_ns)t.tv_nsec
        - (casfw_ns)t0.tv_nsec;
}

static void io(void *ctx, uint64_t first, uint32_t n, const double *dac, unsigned n_dac,
               double *adc, unsigned n_adc) {
    (void)ctx;
    (void)first;
    casfw_loopback_io(&world, n, dac, n_dac, adc, n_adc);
}

static void start(void *ctx) {
    (void)ctx;
    casfw_loopback_reset(&world);
}

static void on_signal(int sig) {
    (void)sig;
    stopping = 1;
}

static int open_pty(char *name, size_t cap) {
    int master = posix_openpt(O_RDWR | O_NOCTTY);
    if (master < 0 || grantpt(master) || unlockpt(master)) return -1;
    const char *slave_name = ptsname(master);
    if (!slave_name || strlen(slave_name) >= cap) return -1;
    strcpy(name, slave_name);
    int slave = open(name, O_RDWR | O_NOCTTY);
    if (slave < 0) return -1;
    struct termios tio;
    if (tcgetattr(slave, &tio)) return -1;
    tio.c_iflag &= ~(tcflag_t)(IGNBRK | BRKINT | PARMRK | ISTRIP | INLCR | IGNCR | ICRNL | IXON);
    tio.c_oflag &= ~(tcflag_t)OPOST;
    tio.c_lflag &= ~(tcflag_t)(ECHO | ECHONL | ICANON | ISIG | IEXTEN);
    tio.c_cflag &= ~(tcflag_t)(CSIZE | PARENB);
    tio.c_cflag |= CS8;
    tio.c_cc[VMIN] = 1;
    tio.c_cc[VTIME] = 0;
    if (tcsetattr(slave, TCSANOW, &tio)) return -1;
    close(slave); /* the master then reads a hang-up whenever no host holds the port */
    fcntl(master, F_SETFL, fcntl(master, F_GETFL) | O_NONBLOCK);
    return master;
}

static void usage(void) {
    fprintf(stderr, "usage: casfw-pty [--delay SAMPLES] [--gain LINEAR]\n");
    exit(2);
}

int main(int argc, char **argv) {
    unsigned long delay = 0;
    double gain = 1.0;
    for (int i = 1; i < argc; i++) {
        char *end = NULL;
        if (!strcmp(argv[i], "--delay") && i + 1 < argc) {
            delay = strtoul(argv[++i], &end, 10);
            if (*end || delay > CASFW_LOOPBACK_MAX_DELAY) {
                fprintf(stderr, "casfw-pty: --delay must be 0 .. %u samples\n",
                        CASFW_LOOPBACK_MAX_DELAY);
                return 2;
            }
        } else if (!strcmp(argv[i], "--gain") && i + 1 < argc) {
            gain = strtod(argv[++i], &end);
            if (*end) usage();
        } else {
            usage();
        }
    }
    clock_gettime(CLOCK_MONOTONIC, &t0);
    char name[256];
    int fd = open_pty(name, sizeof name);
    if (fd < 0) {
        perror("casfw-pty: cannot open a pseudo-terminal");
        return 1;
    }
    signal(SIGINT, on_signal);
    signal(SIGTERM, on_signal);
    signal(SIGPIPE, SIG_IGN);
    casfw_config cfg;
    casfw_default_config(&cfg);
    casfw_hal hal = {NULL, real_now, io, start};
    casfw_loopback_init(&world, (uint32_t)delay, gain);
    casfw_init(&board, &cfg, &hal);
    printf("%s\n", name);
    fflush(stdout);

    static uint8_t in[65536], out[65536];
    size_t out_len = 0, out_pos = 0;
    int host_present = 0;
    while (!stopping) {
        struct pollfd p = {fd, POLLIN, 0};
        if (out_pos < out_len || casfw_pending_output(&board)) p.events |= POLLOUT;
        poll(&p, 1, 1);
        int hung_up = (p.revents & (POLLHUP | POLLERR)) != 0;
        if (p.revents & POLLIN) {
            ssize_t n = read(fd, in, sizeof in);
            if (n > 0) {
                host_present = 1;
                casfw_receive(&board, in, (size_t)n);
            } else if (n == 0 || errno == EIO) {
                hung_up = 1;
            }
        }
        if (hung_up) {
            if (host_present) casfw_link_lost(&board);
            host_present = 0;
            out_len = out_pos = 0;
            usleep(2000); /* a hung-up master polls ready at once: back off */
            continue;
        }
        casfw_service(&board);
        while (!stopping) {
            if (out_pos == out_len) {
                out_len = casfw_take_output(&board, out, sizeof out);
                out_pos = 0;
                if (!out_len) break;
            }
            ssize_t n = write(fd, out + out_pos, out_len - out_pos);
            if (n <= 0) break; /* the pty is full: the host is not reading yet */
            out_pos += (size_t)n;
        }
    }
    close(fd);
    return 0;
}
