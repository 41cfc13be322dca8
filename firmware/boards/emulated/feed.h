/**
 * @file feed.h
 * @brief The sensor feed of the emulated boards (native process, QEMU): samples from the host's
 *        simulator instead of an I2C bus.
 *
 * The feed is a byte stream in the frame protocol's framing (COBS, CRC-32; see
 * docs/protocol.md) carrying, per sensor sample, one SAMPLE frame whose gyr, acc,
 * mag and temperature are the register counts the board reads (its timestamp_us
 * and index are the simulator's and are not used: the board stamps and counts
 * samples itself). A BARO frame before a SAMPLE is the barometer's D1 and D2 read
 * with that sample (an MS5611 whose PROM holds feed_baro_prom; the frame's other
 * fields are not used), a GNSS frame before a SAMPLE the receiver's fix that arrived by
 * then. A LOG frame means the feed has ended; its text says why. On QEMU
 * the board asks for each sample by sending one byte on the feed UART; the native
 * board reads the feed from a file. docs/firmware.md specifies it for other feeders.
 */
#ifndef FEED_H
#define FEED_H

#include <stdint.h>

#include "board.h"
#include "imu_proto.h"
#include "imu_sensor.h"
#include "ms5611.h"

/** What a byte of the feed completed. */
typedef enum {
    FEED_MORE = 0,   /**< nothing yet */
    FEED_SAMPLE = 1, /**< a sample */
    FEED_ENDED = 2,  /**< the end of the feed (feed_t.end_text says why) */
} feed_event_t;

/** The barometer's raw conversions that came with a sample. */
typedef struct {
    int valid;   /**< 1 when the sample had a BARO frame before it */
    uint32_t d1; /**< raw pressure conversion, 24 bits */
    uint32_t d2; /**< raw temperature conversion, 24 bits */
} feed_baro_t;

/** The receiver's fix that arrived with a sample. */
typedef struct {
    int valid;            /**< 1 when the sample had a GNSS frame before it */
    imu_proto_gnss_t fix; /**< the fix (its timestamp_us and index are the feeder's) */
} feed_gnss_t;

/** One sample of the feed and what came with it. */
typedef struct {
    imu_raw_sample_t raw;
    int16_t temperature;
    feed_baro_t baro;
    feed_gnss_t gnss;
} feed_sample_t;

/** The emulated MS5611's PROM: the data sheet's typical coefficients C1..C6 (its worked
 *  example), which the host's simulator uses to turn pressures into D1 and D2. */
extern const uint16_t feed_baro_prom[8];

/**
 * @brief The measurement of a sample's barometer conversions, compensated with
 *        feed_baro_prom (the board's board_baro_read), once: *baro is marked used.
 * @return 1 with *out filled, 0 when the sample had none (or it was taken).
 */
int feed_baro_take(feed_baro_t *baro, board_baro_t *out);

/** A feed decoder. All members are private except end_text. */
typedef struct {
    imu_proto_decoder_t decoder;
    uint8_t frame[IMU_PROTO_MAX_FRAME];
    feed_baro_t baro;                  /**< a BARO frame waiting for its SAMPLE */
    feed_gnss_t gnss;                  /**< a GNSS frame waiting for its SAMPLE */
    char end_text[IMU_PROTO_LOG_SIZE]; /**< the LOG text of the end, terminated */
} feed_t;

/** @brief Start decoding a feed. */
void feed_init(feed_t *feed);

/** @brief Push one byte of the feed; on FEED_SAMPLE *sample holds the sample and the
 *         barometer's conversions and the receiver's fix that came with it (if any). */
feed_event_t feed_push(feed_t *feed, uint8_t byte, feed_sample_t *sample);

/** @brief The fix that came with a sample, once: *gnss is marked used. 1 with *fix filled, else 0. */
int feed_gnss_take(feed_gnss_t *gnss, imu_proto_gnss_t *fix);

#endif /* FEED_H */
