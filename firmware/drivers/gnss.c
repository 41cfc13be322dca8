/**
 * @file gnss.c
 * @brief A GNSS receiver on a UART (see gnss.h).
 */
#include "gnss.h"

const gnss_config_t gnss_default_config = {115200u, 100u};

/** Configuring steps: CFG-PRT sent (settling), CFG-MSG awaited, CFG-RATE awaited. */
enum { STEP_PORT = 0, STEP_MESSAGE = 1, STEP_RATE = 2 };

#define CFG_ID_PRT 0x00u
#define CFG_ID_MSG 0x01u
#define CFG_ID_RATE 0x08u

/** The receivers' usual bauds after the configured one: u-blox's default first. */
static const uint32_t USUAL_BAUDS[] = {9600u, 38400u, 57600u, 115200u, 230400u, 19200u, 4800u};
#define USUAL_COUNT (sizeof USUAL_BAUDS / sizeof USUAL_BAUDS[0])

/** 1 once `ms` have passed since `since` (wraps at 2^32 like the board's clock). */
static int elapsed(const gnss_t *g, uint32_t since, uint32_t ms)
{
    return (uint32_t)(g->now_ms - since) >= ms;
}

static void put_u16(uint8_t *p, uint32_t v)
{
    p[0] = (uint8_t)v;
    p[1] = (uint8_t)(v >> 8);
}

static void put_u32(uint8_t *p, uint32_t v)
{
    put_u16(p, v);
    put_u16(p + 2, v >> 16);
}

/** Queue a CFG frame (the previous one has left: the driver sends one message at a time). */
static void send_cfg(gnss_t *g, uint8_t id, const uint8_t *payload, uint16_t len)
{
    g->tx_len = (uint16_t)ubx_encode(UBX_CLASS_CFG, id, payload, len, g->tx, sizeof g->tx);
}

/** CFG-PRT for UART1: 8N1 at the configured baud, UBX and NMEA in, UBX out. */
static void send_port(gnss_t *g)
{
    uint8_t p[20] = {0};
    p[0] = 1;                    /* portID: UART1 */
    put_u32(p + 4, 0x000008C0u); /* mode: charLen 8 bits (bits 7..6 = 11), no parity (bits 11..9 = 100), 1 stop */
    put_u32(p + 8, g->config.baud);
    put_u16(p + 12, 0x0003u);    /* inProtoMask: UBX, NMEA */
    put_u16(p + 14, 0x0001u);    /* outProtoMask: UBX */
    send_cfg(g, CFG_ID_PRT, p, sizeof p);
}

/** CFG-MSG (current port): NAV-PVT at every navigation epoch. */
static void send_message(gnss_t *g)
{
    const uint8_t p[3] = {UBX_CLASS_NAV, UBX_ID_NAV_PVT, 1};
    send_cfg(g, CFG_ID_MSG, p, sizeof p);
}

/** CFG-RATE: the configured epoch period, one measurement per epoch, GPS time. */
static void send_rate(gnss_t *g)
{
    uint8_t p[6];
    put_u16(p, g->config.meas_rate_ms);
    put_u16(p + 2, 1);
    put_u16(p + 4, 1);
    send_cfg(g, CFG_ID_RATE, p, sizeof p);
}

/** Candidate baud k of the search: the configured one, then the usual ones without it. */
static uint32_t candidate(const gnss_t *g, uint8_t k)
{
    unsigned i, n = 0;
    if (k == 0) {
        return g->config.baud;
    }
    for (i = 0; i < USUAL_COUNT; ++i) {
        if (USUAL_BAUDS[i] != g->config.baud && ++n == k) {
            return USUAL_BAUDS[i];
        }
    }
    return g->config.baud;
}

uint8_t gnss_candidates(const gnss_t *g)
{
    unsigned i, n = 1;
    for (i = 0; i < USUAL_COUNT; ++i) {
        n += USUAL_BAUDS[i] != g->config.baud;
    }
    return (uint8_t)n;
}

static void listen_at(gnss_t *g, uint8_t k)
{
    g->state = GNSS_SEARCHING;
    g->step = k;
    g->baud = candidate(g, k);
    g->started_ms = g->now_ms;
    ++g->counters.searches;
}

void gnss_init(gnss_t *g, const gnss_config_t *config, uint32_t now_ms)
{
    g->config = *config;
    ubx_parser_init(&g->ubx);
    nmea_parser_init(&g->nmea);
    g->counters.searches = g->counters.found = g->counters.lost = 0;
    g->counters.timeouts = g->counters.naks = g->counters.fixes = 0;
    g->tx_len = 0;
    g->rmc_valid = 0;
    g->attempts = g->waiting = 0;
    g->found_baud = config->baud;
    g->now_ms = g->last_heard_ms = now_ms;
    listen_at(g, 0);
}

/** Send the current step's message (again) and wait for its answer. */
static void ask(gnss_t *g)
{
    if (g->step == STEP_MESSAGE) {
        send_message(g);
    } else {
        send_rate(g);
    }
    ++g->attempts;
    g->waiting = 1;
    g->started_ms = g->now_ms;
}

static void start_step(gnss_t *g, uint8_t step)
{
    g->step = step;
    g->attempts = 0;
    ask(g);
}

static void run(gnss_t *g, gnss_state_t state, uint32_t baud)
{
    g->state = (uint8_t)state;
    g->baud = baud;
    g->waiting = 0;
    g->last_heard_ms = g->now_ms;
}

/** A receiver answered during the search: configure it. */
static void found(gnss_t *g)
{
    ++g->counters.found;
    g->found_baud = g->baud;
    g->state = GNSS_CONFIGURING;
    g->step = STEP_PORT;
    g->started_ms = g->now_ms;
    send_port(g);
}

/** CFG-MSG got no answer GNSS_ATTEMPTS times, or a NAK. */
static void message_failed(gnss_t *g)
{
    if (g->baud != g->found_baud) {
        /* CFG-PRT may not have taken: ask again where the receiver was found */
        g->baud = g->found_baud;
        start_step(g, STEP_MESSAGE);
    } else {
        run(g, GNSS_RUNNING_NMEA, g->found_baud); /* not a UBX receiver */
    }
}

static void on_ack(gnss_t *g, uint8_t id, const uint8_t *payload, uint16_t len)
{
    const uint8_t expected = g->step == STEP_MESSAGE ? CFG_ID_MSG : CFG_ID_RATE;
    if (g->state != GNSS_CONFIGURING || !g->waiting || len != 2 || payload[0] != UBX_CLASS_CFG ||
        payload[1] != expected) {
        return; /* not the answer awaited (CFG-PRT's, or late) */
    }
    g->waiting = 0;
    if (id == UBX_ID_ACK_NAK) {
        ++g->counters.naks;
        if (g->step == STEP_MESSAGE) {
            run(g, GNSS_RUNNING_NMEA, g->baud);
            return;
        }
    }
    if (g->step == STEP_MESSAGE) {
        start_step(g, STEP_RATE);
    } else {
        run(g, GNSS_RUNNING_UBX, g->baud); /* a refused rate leaves the receiver at its own */
    }
}

static int deliver_nav_pvt(gnss_t *g, const uint8_t *payload, uint16_t len)
{
    ubx_nav_pvt_t pvt;
    gnss_fix_t *f = &g->fix;
    if (!ubx_nav_pvt(payload, len, &pvt)) {
        return 0;
    }
    f->time_ms = pvt.itow_ms;
    f->fix_type = pvt.fix_type;
    f->fix_ok = pvt.fix_ok;
    f->num_sv = pvt.num_sv;
    f->has_velocity = 1;
    f->lat_1e7deg = pvt.lat_1e7deg;
    f->lon_1e7deg = pvt.lon_1e7deg;
    f->height_mm = pvt.height_mm;
    f->h_acc_mm = pvt.h_acc_mm;
    f->v_acc_mm = pvt.v_acc_mm;
    f->vel_ned_mm_s[0] = pvt.vel_ned_mm_s[0];
    f->vel_ned_mm_s[1] = pvt.vel_ned_mm_s[1];
    f->vel_ned_mm_s[2] = pvt.vel_ned_mm_s[2];
    f->s_acc_mm_s = pvt.s_acc_mm_s;
    f->speed_mm_s = 0;
    f->course_1e5deg = 0;
    f->hdop_cent = pvt.p_dop_cent;
    ++g->counters.fixes;
    return 1;
}

/** GGA is the epoch's fix; the RMC of the same second (sent before it) adds speed and course. */
static int deliver_nmea(gnss_t *g)
{
    nmea_gga_t gga;
    gnss_fix_t *f = &g->fix;
    if (nmea_rmc(&g->nmea, &g->rmc)) {
        g->rmc_valid = 1;
        return 0;
    }
    if (!nmea_gga(&g->nmea, &gga)) {
        return 0;
    }
    f->time_ms = gga.time_ms;
    f->fix_type = gga.quality > 0 ? UBX_FIX_3D : UBX_FIX_NONE;
    f->fix_ok = gga.quality > 0;
    f->num_sv = gga.num_sv;
    f->has_velocity = 0;
    f->lat_1e7deg = gga.lat_1e7deg;
    f->lon_1e7deg = gga.lon_1e7deg;
    f->height_mm = gga.alt_msl_mm + gga.geoid_sep_mm;
    f->h_acc_mm = f->v_acc_mm = f->s_acc_mm_s = 0;
    f->vel_ned_mm_s[0] = f->vel_ned_mm_s[1] = f->vel_ned_mm_s[2] = 0;
    f->hdop_cent = gga.hdop_cent;
    if (g->rmc_valid && g->rmc.time_ms == gga.time_ms && g->rmc.active) {
        f->speed_mm_s = g->rmc.speed_mm_s;
        f->course_1e5deg = g->rmc.course_1e5deg;
    } else {
        f->speed_mm_s = f->course_1e5deg = 0;
    }
    ++g->counters.fixes;
    return 1;
}

/** A valid frame or sentence: the receiver is there. */
static void heard(gnss_t *g)
{
    g->last_heard_ms = g->now_ms;
    if (g->state == GNSS_SEARCHING) {
        found(g);
    }
}

int gnss_push(gnss_t *g, uint8_t byte)
{
    int fix = 0;
    if (ubx_parser_push(&g->ubx, byte)) {
        uint16_t len;
        const uint8_t *payload = ubx_frame_payload(&g->ubx, &len);
        const uint8_t cls = ubx_frame_class(&g->ubx), id = ubx_frame_id(&g->ubx);
        heard(g);
        if (cls == UBX_CLASS_ACK && (id == UBX_ID_ACK_ACK || id == UBX_ID_ACK_NAK)) {
            on_ack(g, id, payload, len);
        } else if (cls == UBX_CLASS_NAV && id == UBX_ID_NAV_PVT && g->state == GNSS_RUNNING_UBX) {
            fix = deliver_nav_pvt(g, payload, len);
        }
    }
    if (nmea_parser_push(&g->nmea, byte)) {
        heard(g);
        if (g->state == GNSS_RUNNING_NMEA) {
            fix = deliver_nmea(g);
        }
    }
    return fix;
}

void gnss_poll(gnss_t *g, uint32_t now_ms)
{
    g->now_ms = now_ms;
    switch (g->state) {
    case GNSS_SEARCHING:
        if (elapsed(g, g->started_ms, GNSS_LISTEN_MS)) {
            listen_at(g, (uint8_t)((g->step + 1u) % gnss_candidates(g)));
        }
        break;
    case GNSS_CONFIGURING:
        if (g->step == STEP_PORT) {
            if (elapsed(g, g->started_ms, GNSS_BAUD_SETTLE_MS)) {
                g->baud = g->config.baud;
                start_step(g, STEP_MESSAGE);
            }
        } else if (g->waiting && elapsed(g, g->started_ms, GNSS_ACK_TIMEOUT_MS)) {
            ++g->counters.timeouts;
            if (g->attempts < GNSS_ATTEMPTS) {
                ask(g);
            } else if (g->step == STEP_MESSAGE) {
                message_failed(g);
            } else {
                run(g, GNSS_RUNNING_UBX, g->baud); /* NAV-PVT is on; the rate stays the receiver's */
            }
        }
        break;
    default: /* running */
        if (elapsed(g, g->last_heard_ms, GNSS_LOST_MS)) {
            ++g->counters.lost;
            listen_at(g, 0);
        }
        break;
    }
}

size_t gnss_take_tx(gnss_t *g, uint8_t *out, size_t cap)
{
    size_t i, n = g->tx_len < cap ? g->tx_len : cap;
    for (i = 0; i < n; ++i) {
        out[i] = g->tx[i];
    }
    for (i = n; i < g->tx_len; ++i) {
        g->tx[i - n] = g->tx[i];
    }
    g->tx_len = (uint16_t)(g->tx_len - n);
    return n;
}

uint32_t gnss_baud(const gnss_t *g)
{
    return g->baud;
}

gnss_state_t gnss_state(const gnss_t *g)
{
    return (gnss_state_t)g->state;
}

const gnss_fix_t *gnss_fix(const gnss_t *g)
{
    return &g->fix;
}
