/**
 * @file feed.c
 * @brief Sensor feed decoding (see feed.h).
 */
#include "feed.h"

/* MS5611-01BA03 data sheet, "typical values": C1..C6 of its compensation example (words 0 and 7,
 * the factory data and the CRC, are not used by the compensation). */
const uint16_t feed_baro_prom[8] = {0, 40127, 36924, 23317, 23282, 33464, 28312, 0};

int feed_baro_take(feed_baro_t *baro, board_baro_t *out)
{
    ms5611_reading_t r;
    if (!baro->valid) {
        return 0;
    }
    baro->valid = 0;
    ms5611_compensate(feed_baro_prom, baro->d1, baro->d2, &r);
    out->d1 = r.d1;
    out->d2 = r.d2;
    out->pressure_pa = r.pressure_pa;
    out->temperature_cdeg = r.temperature_cdeg;
    return 1;
}

int feed_gnss_take(feed_gnss_t *gnss, imu_proto_gnss_t *fix)
{
    if (!gnss->valid) {
        return 0;
    }
    gnss->valid = 0;
    *fix = gnss->fix;
    return 1;
}

void feed_init(feed_t *feed)
{
    imu_proto_decoder_init(&feed->decoder, feed->frame, sizeof feed->frame);
    feed->baro.valid = 0;
    feed->gnss.valid = 0;
    feed->end_text[0] = '\0';
}

feed_event_t feed_push(feed_t *feed, uint8_t byte, feed_sample_t *sample)
{
    imu_proto_frame_t frame;
    if (!imu_proto_decoder_push(&feed->decoder, byte, &frame)) {
        return FEED_MORE;
    }
    if (frame.msg_id == IMU_PROTO_MSG_SAMPLE) {
        imu_proto_sample_t s;
        int i;
        if (imu_proto_sample_unpack(&s, frame.payload, frame.payload_len) != IMU_PROTO_OK) {
            return FEED_MORE;
        }
        for (i = 0; i < 3; ++i) {
            sample->raw.gyr[i] = s.gyr[i];
            sample->raw.acc[i] = s.acc[i];
            sample->raw.mag[i] = s.mag[i];
        }
        sample->temperature = s.temperature;
        sample->baro = feed->baro;
        sample->gnss = feed->gnss;
        feed->baro.valid = 0;
        feed->gnss.valid = 0;
        return FEED_SAMPLE;
    }
    if (frame.msg_id == IMU_PROTO_MSG_GNSS) {
        feed->gnss.valid = imu_proto_gnss_unpack(&feed->gnss.fix, frame.payload, frame.payload_len) == IMU_PROTO_OK;
        return FEED_MORE;
    }
    if (frame.msg_id == IMU_PROTO_MSG_BARO) {
        imu_proto_baro_t b;
        if (imu_proto_baro_unpack(&b, frame.payload, frame.payload_len) == IMU_PROTO_OK) {
            feed->baro.valid = 1;
            feed->baro.d1 = b.d1 & 0xFFFFFFu;
            feed->baro.d2 = b.d2 & 0xFFFFFFu;
        }
        return FEED_MORE;
    }
    if (frame.msg_id == IMU_PROTO_MSG_LOG) {
        imu_proto_log_t log;
        if (imu_proto_log_unpack(&log, frame.payload, frame.payload_len) != IMU_PROTO_OK) {
            return FEED_MORE;
        }
        for (size_t i = 0; i < log.text_len; ++i) {
            feed->end_text[i] = log.text[i];
        }
        feed->end_text[log.text_len] = '\0';
        return FEED_ENDED;
    }
    return FEED_MORE;
}
