/**
 * @file feed.c
 * @brief Sensor feed decoding (see feed.h).
 */
#include "feed.h"

void feed_init(feed_t *feed)
{
    imu_proto_decoder_init(&feed->decoder, feed->frame, sizeof feed->frame);
    feed->end_text[0] = '\0';
}

feed_event_t feed_push(feed_t *feed, uint8_t byte, imu_raw_sample_t *raw, int16_t *temperature)
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
            raw->gyr[i] = s.gyr[i];
            raw->acc[i] = s.acc[i];
            raw->mag[i] = s.mag[i];
        }
        *temperature = s.temperature;
        return FEED_SAMPLE;
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
