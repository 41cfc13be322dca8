/**
 * @file feed.h
 * @brief The sensor feed of the emulated boards (native process, QEMU): samples from the host's
 *        simulator instead of an I2C bus.
 *
 * The feed is a byte stream in the frame protocol's framing (COBS, CRC-32; see
 * docs/protocol.md) carrying, per sensor sample, one SAMPLE frame whose gyr, acc,
 * mag and temperature are the register counts the board reads (its timestamp_us
 * and index are the simulator's and are not used: the board stamps and counts
 * samples itself). A LOG frame means the feed has ended; its text says why. On QEMU
 * the board asks for each sample by sending one byte on the feed UART; the native
 * board reads the feed from a file. docs/firmware.md specifies it for other feeders.
 */
#ifndef FEED_H
#define FEED_H

#include <stdint.h>

#include "imu_proto.h"
#include "imu_sensor.h"

/** What a byte of the feed completed. */
typedef enum {
    FEED_MORE = 0,   /**< nothing yet */
    FEED_SAMPLE = 1, /**< a sample */
    FEED_ENDED = 2,  /**< the end of the feed (feed_t.end_text says why) */
} feed_event_t;

/** A feed decoder. All members are private except end_text. */
typedef struct {
    imu_proto_decoder_t decoder;
    uint8_t frame[IMU_PROTO_MAX_FRAME];
    char end_text[IMU_PROTO_LOG_SIZE]; /**< the LOG text of the end, terminated */
} feed_t;

/** @brief Start decoding a feed. */
void feed_init(feed_t *feed);

/** @brief Push one byte of the feed; on FEED_SAMPLE the sample is in *raw and *temperature. */
feed_event_t feed_push(feed_t *feed, uint8_t byte, imu_raw_sample_t *raw, int16_t *temperature);

#endif /* FEED_H */
