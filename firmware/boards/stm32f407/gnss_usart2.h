/**
 * @file gnss_usart2.h
 * @brief The reference board's GNSS receiver on USART2 (PA2 TX, PA3 RX; docs/firmware.md):
 *        the ring-buffered USART of boards/stm32f4/uart.h under the receiver driver of
 *        drivers/gnss.h (search baud by baud, configure, fixes), its fixes in the GNSS
 *        message's units.
 */
#ifndef GNSS_USART2_H
#define GNSS_USART2_H

#include <stdint.h>

#include "imu_proto.h"

/**
 * @brief Start the USART (its clock and pins already enabled by the board) and the driver.
 * @param pclk1_hz USART2's bus clock; @param priority its interrupt's; @param now_ms the time
 */
void gnss_usart2_init(uint32_t pclk1_hz, uint8_t priority, uint32_t now_ms);

/**
 * @brief Give the driver what the receiver sent and the time, send what it asks, follow its
 *        baud; call every few ms (each sample).
 * @return 1 with *fix filled (its fields but timestamp_us and index) when a fix completed since the last call.
 */
int gnss_usart2_poll(uint32_t now_ms, imu_proto_gnss_t *fix);

/**
 * @brief What changed with the receiver since the last call, as a LOG line (found, configured,
 *        NMEA only, lost, no answer after a whole search, damaged frames at most every 10 s);
 *        NULL when nothing did. @param level the line's LOG level
 */
const char *gnss_usart2_news(uint8_t *level);

#endif /* GNSS_USART2_H */
