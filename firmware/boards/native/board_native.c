/**
 * @file board_native.c
 * @brief The native board: the application as a host process, its UART a pseudo-terminal
 *        or a TCP server on 127.0.0.1, its sensors a feed file written by the host's
 *        simulator (boards/emulated/feed.h).
 *
 *     imulink-native [--pty | --tcp PORT] [--feed FILE] [--fast] [--profile NAME] [--rate HZ] [--filter NAME]
 *
 * The first line on stdout is what a host opens: the pty's path or socket://127.0.0.1:PORT.
 * Real time (default): samples are due at the sample rate of the wall clock (late ones are
 * caught up: boards/emulated/schedule.h), and when the host does not drain the link, samples
 * are dropped as on a board whose UART buffer is full. Fast
 * (--fast): a sample is due whenever the link has room, so the run goes as fast as the host
 * reads and nothing is dropped. One TCP client at a time; every new one is greeted with HELLO.
 * SIGINT / SIGTERM end the process with status 0.
 */
#define _DEFAULT_SOURCE /* cfmakeraw */
#define _XOPEN_SOURCE 600 /* posix_openpt, grantpt, unlockpt, ptsname */

#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "app.h"
#include "board.h"
#include "feed.h"
#include "options.h"
#include "schedule.h"

/** Bytes a real-time board buffers for a slow or absent host before it drops samples. */
#define REALTIME_BACKLOG 65536u
/** Bytes a fast board lets pile up before it waits for the host to read. */
#define FAST_BACKLOG 16384u

static struct {
    int fast;
    int server;            /* TCP listening socket, or -1 */
    int client;            /* TCP client, or -1 */
    int pty_master, pty_slave;
    int new_client;        /* a client connected since the main loop last looked */
    uint8_t out[REALTIME_BACKLOG];
    size_t out_len;
    struct timespec origin;
    int clock_running;
    schedule_t schedule;   /* real time: when samples are due */
    FILE *feed_file;
    const char *feed_path;
    feed_t feed;
    feed_sample_t sample; /* the last sample and what came with it */
    char message[256];
} native;

static volatile sig_atomic_t stop_requested;
/** A pipe the signal handler writes to, which board_idle's poll watches: a signal that comes
 *  while the application runs (not in poll, where it would interrupt the wait) would
 *  otherwise be seen only after the next event, which may never come. */
static int wake_pipe[2] = {-1, -1};

static void on_signal(int signum)
{
    const int saved = errno;
    (void)signum;
    stop_requested = 1;
    if (wake_pipe[1] >= 0) {
        ssize_t ignored = write(wake_pipe[1], "", 1); /* full: a wake-up is pending already */
        (void)ignored;
    }
    errno = saved;
}

static uint64_t now_ns(void)
{
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (uint64_t)(t.tv_sec - native.origin.tv_sec) * 1000000000u + (uint64_t)t.tv_nsec -
           (uint64_t)native.origin.tv_nsec;
}

/* --------------------------------------------------------------------------- link */

static int link_fd(void)
{
    return native.server >= 0 ? native.client : native.pty_master;
}

static void drop_client(void)
{
    close(native.client);
    native.client = -1;
    native.out_len = 0;
}

/** Send what the peer takes now; without a peer (no TCP client) the output is lost, as on a
 *  UART with nothing attached. */
static void send_pending(void)
{
    const int fd = link_fd();
    ssize_t sent;
    if (fd < 0) {
        native.out_len = 0;
        return;
    }
    while (native.out_len > 0) {
        sent = write(fd, native.out, native.out_len);
        if (sent <= 0) {
            if (sent < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) {
                return;
            }
            if (native.server >= 0) {
                drop_client();
            }
            native.out_len = 0;
            return;
        }
        memmove(native.out, native.out + sent, native.out_len - (size_t)sent);
        native.out_len -= (size_t)sent;
    }
}

static void wait_writable(void)
{
    struct pollfd p = {link_fd(), POLLOUT, 0};
    if (p.fd >= 0) {
        (void)poll(&p, 1, 50);
    }
    send_pending();
}

size_t board_link_read(uint8_t *buf, size_t cap)
{
    const int fd = link_fd();
    ssize_t got;
    if (fd < 0) {
        return 0;
    }
    got = read(fd, buf, cap);
    if (got > 0) {
        return (size_t)got;
    }
    if (got == 0 && native.server >= 0) {
        drop_client(); /* the client left */
    }
    return 0;
}

size_t board_link_space(void)
{
    return sizeof native.out - native.out_len;
}

void board_link_write(const uint8_t *data, size_t len)
{
    while (len > 0 && !stop_requested) {
        size_t room = board_link_space();
        size_t n = len < room ? len : room;
        memcpy(native.out + native.out_len, data, n);
        native.out_len += n;
        data += n;
        len -= n;
        send_pending();
        if (len > 0) {
            wait_writable();
        }
    }
}

void board_link_flush(void)
{
    while (native.out_len > 0 && link_fd() >= 0 && !stop_requested) {
        wait_writable();
    }
}

/* --------------------------------------------------------------------------- clocks */

uint64_t board_time_us(void)
{
    return now_ns() / 1000u;
}

uint32_t board_cycles(void)
{
    return (uint32_t)now_ns();
}

uint32_t board_cycle_hz(void)
{
    return 1000000000u;
}

void board_sample_clock_start(uint32_t rate_mhz)
{
    schedule_start(&native.schedule, board_time_us(), rate_mhz);
    native.clock_running = 1;
}

void board_sample_clock_stop(void)
{
    native.clock_running = 0;
}

/** In fast mode a sample is due whenever the host has drained the link far enough. */
static int fast_sample_due(void)
{
    return link_fd() >= 0 && native.out_len < FAST_BACKLOG;
}

uint32_t board_sample_ticks(void)
{
    if (!native.clock_running) {
        return 0;
    }
    if (native.fast) {
        return (uint32_t)fast_sample_due();
    }
    return schedule_ticks(&native.schedule, board_time_us());
}

/* --------------------------------------------------------------------------- sensors */

board_sensors_result_t board_sensors_init(const char **message)
{
    if (native.feed_file == NULL) {
        *message = "no sensors: this native board has no sensor feed (--feed FILE)";
        return BOARD_SENSORS_FAILED;
    }
    snprintf(native.message, sizeof native.message, "sensor feed %s: an emulated GY-86", native.feed_path);
    *message = native.message;
    return BOARD_SENSORS_OK;
}

board_sensors_result_t board_sensors_read(imu_raw_sample_t *raw, int16_t *temperature, const char **message)
{
    int c;
    if (native.feed_file == NULL) {
        *message = "no sensor feed";
        return BOARD_SENSORS_FAILED;
    }
    while ((c = getc(native.feed_file)) != EOF) {
        switch (feed_push(&native.feed, (uint8_t)c, &native.sample)) {
        case FEED_SAMPLE:
            *raw = native.sample.raw;
            *temperature = native.sample.temperature;
            return BOARD_SENSORS_OK;
        case FEED_ENDED:
            *message = native.feed.end_text;
            return BOARD_SENSORS_ENDED;
        case FEED_MORE:
            break;
        }
    }
    *message = "end of the sensor feed";
    return BOARD_SENSORS_ENDED;
}

int board_baro_read(uint64_t now_us, board_baro_t *out)
{
    (void)now_us; /* the feed's conversions came with the sample */
    return feed_baro_take(&native.sample.baro, out);
}

int board_gnss_read(uint64_t now_us, imu_proto_gnss_t *fix)
{
    (void)now_us; /* the feed's fix came with the sample */
    return feed_gnss_take(&native.sample.gnss, fix);
}

/* --------------------------------------------------------------------------- system */

void board_idle(void)
{
    struct pollfd p[3];
    nfds_t n = 0;
    int timeout_ms = -1;
    const int fd = link_fd();
    if (native.server >= 0 && native.client < 0) {
        p[n].fd = native.server;
        p[n++].events = POLLIN;
    }
    if (fd >= 0) {
        p[n].fd = fd;
        p[n++].events = (short)(POLLIN | (native.out_len > 0 ? POLLOUT : 0));
    }
    if (wake_pipe[0] >= 0) {
        p[n].fd = wake_pipe[0];
        p[n++].events = POLLIN;
    }
    if (native.clock_running) {
        if (!native.fast) {
            const uint64_t now = board_time_us(), next = schedule_next_us(&native.schedule);
            timeout_ms = now >= next ? 0 : (int)((next - now + 999u) / 1000u);
        } else if (fast_sample_due()) {
            timeout_ms = 0;
        }
    }
    if (poll(p, n, timeout_ms) > 0 && native.server >= 0 && native.client < 0 && (p[0].revents & POLLIN)) {
        const int client = accept(native.server, NULL, NULL);
        if (client >= 0) {
            const int one = 1;
            fcntl(client, F_SETFL, O_NONBLOCK);
            setsockopt(client, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
            native.client = client;
            native.out_len = 0;
            native.new_client = 1;
        }
    }
    send_pending();
}

void board_restart(void)
{
    clock_gettime(CLOCK_MONOTONIC, &native.origin); /* uptime starts again, as after a power cycle */
    native.clock_running = 0;
}

const char *board_news(uint8_t *level)
{
    (void)level;
    return 0; /* the feed's receiver has no state of its own to report */
}

const char *board_start_up_problem(void)
{
    return 0;
}

int board_has_bootloader(void)
{
    return 0;
}

void board_enter_bootloader(void)
{
}

/* --------------------------------------------------------------------------- start-up */

static void usage(FILE *to)
{
    fprintf(to,
            "usage: imulink-native [--pty | --tcp PORT] [--feed FILE] [--fast] [options]\n"
            "The imulink board application as a host process (the emulated board).\n"
            "  --pty            serve on a pseudo-terminal (default); its path is printed\n"
            "  --tcp PORT       serve on 127.0.0.1:PORT (0: any free port); socket://... is printed\n"
            "  --feed FILE      sensor samples (SAMPLE frames, see docs/firmware.md); without it the\n"
            "                   board has no sensors and only injection mode works\n"
            "  --fast           a sample whenever the host has read the last ones (default: real time)\n"
            "%s",
            options_usage);
}

static void fail(const char *what)
{
    fprintf(stderr, "imulink-native: %s\n", what);
    exit(2);
}

static void open_pty(void)
{
    struct termios raw;
    const char *name;
    native.pty_master = posix_openpt(O_RDWR | O_NOCTTY);
    if (native.pty_master < 0 || grantpt(native.pty_master) != 0 || unlockpt(native.pty_master) != 0 ||
        (name = ptsname(native.pty_master)) == NULL) {
        fail("cannot create a pseudo-terminal");
    }
    /* Keep the slave open ourselves: the master then never reads EIO while no host has it open. */
    native.pty_slave = open(name, O_RDWR | O_NOCTTY);
    if (native.pty_slave < 0 || tcgetattr(native.pty_slave, &raw) != 0) {
        fail("cannot open the pseudo-terminal");
    }
    cfmakeraw(&raw); /* no echo, no line editing, no CR/LF translation */
    tcsetattr(native.pty_slave, TCSANOW, &raw);
    fcntl(native.pty_master, F_SETFL, O_NONBLOCK);
    printf("%s\n", name);
}

static void open_tcp(const char *port_text)
{
    struct sockaddr_in address;
    socklen_t length = sizeof address;
    char *end;
    const long port = strtol(port_text, &end, 10);
    const int one = 1;
    if (*port_text == '\0' || *end != '\0' || port < 0 || port > 65535) {
        fail("--tcp needs a port number (0: any free port)");
    }
    native.server = socket(AF_INET, SOCK_STREAM, 0);
    memset(&address, 0, sizeof address);
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    address.sin_port = htons((uint16_t)port);
    setsockopt(native.server, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    if (native.server < 0 || bind(native.server, (struct sockaddr *)&address, sizeof address) != 0 ||
        listen(native.server, 4) != 0 || getsockname(native.server, (struct sockaddr *)&address, &length) != 0) {
        fprintf(stderr, "imulink-native: cannot listen on 127.0.0.1:%ld: %s\n", port, strerror(errno));
        exit(2);
    }
    fcntl(native.server, F_SETFL, O_NONBLOCK);
    printf("socket://127.0.0.1:%u\n", (unsigned)ntohs(address.sin_port));
}

int main(int argc, char **argv)
{
    static app_t app;
    app_config_t config;
    const char *tcp_port = NULL;
    struct sigaction action;
    int i;

    options_defaults(&config, "native");
    native.server = native.client = native.pty_master = native.pty_slave = -1;
    for (i = 1; i < argc; ++i) {
        const char *value = i + 1 < argc ? argv[i + 1] : NULL;
        const char *error = "";
        const int applied = options_apply(&config, argv[i], value, &error);
        if (applied < 0) {
            fail(error);
        } else if (applied > 0) {
            ++i;
        } else if (strcmp(argv[i], "--pty") == 0) {
            tcp_port = NULL;
        } else if (strcmp(argv[i], "--tcp") == 0 && value != NULL) {
            tcp_port = argv[++i];
        } else if (strcmp(argv[i], "--feed") == 0 && value != NULL) {
            native.feed_path = argv[++i];
        } else if (strcmp(argv[i], "--fast") == 0) {
            native.fast = 1;
        } else if (strcmp(argv[i], "--help") == 0 || strcmp(argv[i], "-h") == 0) {
            usage(stdout);
            return 0;
        } else {
            fprintf(stderr, "imulink-native: unknown option or missing value: %s\n", argv[i]);
            usage(stderr);
            return 2;
        }
    }
    if (native.feed_path != NULL && (native.feed_file = fopen(native.feed_path, "rb")) == NULL) {
        fprintf(stderr, "imulink-native: cannot read the sensor feed %s: %s\n", native.feed_path, strerror(errno));
        return 2;
    }
    feed_init(&native.feed);

    if (pipe(wake_pipe) != 0) {
        fail("cannot create the signal pipe");
    }
    for (i = 0; i < 2; ++i) {
        fcntl(wake_pipe[i], F_SETFL, O_NONBLOCK);
        fcntl(wake_pipe[i], F_SETFD, FD_CLOEXEC);
    }
    memset(&action, 0, sizeof action);
    action.sa_handler = on_signal; /* no SA_RESTART: poll() returns at once */
    sigaction(SIGINT, &action, NULL);
    sigaction(SIGTERM, &action, NULL);
    signal(SIGPIPE, SIG_IGN); /* a client that left is seen by write(), not a signal */

    if (tcp_port != NULL) {
        open_tcp(tcp_port);
    } else {
        open_pty();
    }
    fflush(stdout);

    clock_gettime(CLOCK_MONOTONIC, &native.origin);
    app_init(&app, &config);
    while (!stop_requested) {
        const app_result_t result = app_poll(&app);
        if (result == APP_RESTART) {
            board_restart();
            app_init(&app, &config);
        } else if (native.new_client) {
            native.new_client = 0;
            app_send_hello(&app);
        } else if (result == APP_IDLE) {
            board_idle();
        }
    }
    return 0;
}
