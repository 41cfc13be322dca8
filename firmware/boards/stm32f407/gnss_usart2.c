/**
 * @file gnss_usart2.c
 * @brief The GNSS receiver on USART2 (see gnss_usart2.h).
 */
#include "gnss_usart2.h"

#include "gnss.h"
#include "stm32f4.h"
#include "uart.h"

static uart_t gnss_uart;
static gnss_t receiver;
static uint32_t bus_hz;     /* USART2's bus clock, Hz */
static uint32_t uart_baud;  /* the baud USART2 runs at now */

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
    uart_init(&gnss_uart, USART2, IRQ_USART2, pclk1_hz, uart_baud, priority);
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
