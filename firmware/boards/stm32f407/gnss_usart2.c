/**
 * @file gnss_usart2.c
 * @brief The GNSS receiver on USART2 (see gnss_usart2.h).
 */
#include "gnss_usart2.h"

#include "gnss.h"
#include "stm32f4.h"
#include "text.h"
#include "uart.h"

#define DAMAGE_REPORT_MS 10000u /* damaged frames are reported at most this often */

static uart_t gnss_uart;
static gnss_t receiver;
static uint32_t bus_hz;     /* USART2's bus clock, Hz */
static uint32_t uart_baud;  /* the baud USART2 runs at now */
static uint8_t reported_state; /* gnss_state_t the last news was about */
static uint32_t searches_reported; /* counters.searches when "no answer" was last said */
static uint32_t damaged_reported;  /* checksum errors already reported */
static uint32_t damage_report_ms;  /* when damaged frames were last reported */
static uint32_t last_ms;           /* the time of the last poll */
static char news[96];

void usart2_irq_handler(void);

void usart2_irq_handler(void)
{
    uart_irq(&gnss_uart);
}

void gnss_usart2_init(uint32_t pclk1_hz, uint8_t priority, uint32_t now_ms)
{
    bus_hz = pclk1_hz;
    gnss_init(&receiver, &gnss_default_config, now_ms);
    uart_baud = gnss_baud(&receiver);
    reported_state = (uint8_t)GNSS_SEARCHING;
    searches_reported = damaged_reported = 0;
    damage_report_ms = last_ms = now_ms;
    uart_init(&gnss_uart, USART2, IRQ_USART2, pclk1_hz, uart_baud, priority);
}

static uint32_t damaged_frames(void)
{
    return receiver.ubx.checksum_errors + receiver.nmea.checksum_errors;
}

const char *gnss_usart2_news(uint8_t *level)
{
    const gnss_state_t state = gnss_state(&receiver);
    const uint32_t searches = receiver.counters.searches;
    text_t t;
    text_start(&t, news, sizeof news);
    *level = IMU_PROTO_LOG_LEVEL_INFO;
    if (state != (gnss_state_t)reported_state) {
        const gnss_state_t before = (gnss_state_t)reported_state;
        reported_state = (uint8_t)state;
        searches_reported = searches;
        if (state == GNSS_CONFIGURING) {
            text_add(&t, "GNSS: receiver found at ");
            text_add_uint(&t, gnss_baud(&receiver));
            text_add(&t, " baud");
        } else if (state == GNSS_RUNNING_UBX) {
            text_add(&t, "GNSS: u-blox receiver configured: NAV-PVT every ");
            text_add_uint(&t, gnss_default_config.meas_rate_ms);
            text_add(&t, " ms at ");
            text_add_uint(&t, gnss_baud(&receiver));
            text_add(&t, " baud");
        } else if (state == GNSS_RUNNING_NMEA) {
            *level = IMU_PROTO_LOG_LEVEL_WARNING;
            text_add(&t, "GNSS: the receiver takes no UBX configuration: its NMEA GGA + RMC at ");
            text_add_uint(&t, gnss_baud(&receiver));
            text_add(&t, " baud");
        } else if (before == GNSS_RUNNING_UBX || before == GNSS_RUNNING_NMEA) {
            *level = IMU_PROTO_LOG_LEVEL_WARNING;
            text_add(&t, "GNSS: the receiver went silent: searching again");
        } else {
            return 0; /* configuring failed and the search starts over: said when nothing answers */
        }
        return text_end(&t);
    }
    if (state == GNSS_SEARCHING && searches - searches_reported > gnss_candidates(&receiver)) {
        searches_reported = searches;
        *level = IMU_PROTO_LOG_LEVEL_WARNING;
        text_add(&t, "GNSS: no receiver answers on USART2 (every baud tried; still searching)");
        return text_end(&t);
    }
    if (damaged_frames() != damaged_reported && last_ms - damage_report_ms >= DAMAGE_REPORT_MS) {
        *level = IMU_PROTO_LOG_LEVEL_WARNING;
        text_add(&t, "GNSS: ");
        text_add_uint(&t, damaged_frames() - damaged_reported);
        text_add(&t, " damaged frames from the receiver (checksum) since the last report");
        damaged_reported = damaged_frames();
        damage_report_ms = last_ms;
        return text_end(&t);
    }
    return 0;
}

/** The driver's fix in the GNSS message's fields. */
static void to_message(const gnss_fix_t *f, imu_proto_gnss_t *out)
{
    int k;
    out->time_ms = f->time_ms;
    out->fix_type = f->fix_type;
    out->fix_ok = f->fix_ok;
    out->num_sv = f->num_sv;
    out->has_velocity = f->has_velocity;
    out->lat_1e7deg = f->lat_1e7deg;
    out->lon_1e7deg = f->lon_1e7deg;
    out->height_mm = f->height_mm;
    out->h_acc_mm = f->h_acc_mm;
    out->v_acc_mm = f->v_acc_mm;
    for (k = 0; k < 3; ++k) {
        out->vel_ned_mm_s[k] = f->vel_ned_mm_s[k];
    }
    out->s_acc_mm_s = f->s_acc_mm_s;
}

int gnss_usart2_poll(uint32_t now_ms, imu_proto_gnss_t *fix)
{
    uint8_t bytes[64];
    uint8_t tx[GNSS_TX_CAP];
    size_t n, k, queued;
    int completed = 0;
    /* a ring's worth at most: a receiver that talks faster than the samples come loses bytes
     * in the ring (counted), never makes the sample loop wait */
    for (n = 0; n < UART_RX_SIZE && (k = uart_read(&gnss_uart, bytes, sizeof bytes)) > 0; n += k) {
        size_t i;
        for (i = 0; i < k; ++i) {
            if (gnss_push(&receiver, bytes[i])) {
                to_message(gnss_fix(&receiver), fix);
                completed = 1;
            }
        }
    }
    gnss_poll(&receiver, now_ms);
    last_ms = now_ms;
    queued = gnss_take_tx(&receiver, tx, sizeof tx);
    if (queued > 0) {
        uart_write(&gnss_uart, tx, queued); /* a CFG frame: the ring has room for it */
    }
    if (gnss_baud(&receiver) != uart_baud) {
        uart_baud = gnss_baud(&receiver);
        uart_set_baud(&gnss_uart, bus_hz, uart_baud);
    }
    return completed;
}
