/**
 * @file imu_wire.h
 * @brief Where the core's types meet the protocol's messages (shared/protocol.toml): the
 *        filters' outputs as ESTIMATE and NAV_STATE, and a GNSS message as the nav filter's fix.
 *
 * The filters themselves know neither the wire nor the chips; these conversions are written
 * once, here, and both the board (firmware/app) and the host's replica of it
 * (host/imulink/reference.py, through the cffi build of the core) use them, so that their
 * messages agree bit for bit.
 */
#ifndef IMU_WIRE_H
#define IMU_WIRE_H

#include "imu_filter.h"
#include "imu_proto.h"

/** @brief The nav filter's fix from a GNSS message: usable when it is a 3-D fix (fix_type 3,
 *         or 4 with dead reckoning) within the receiver's masks (fix_ok); the other fields as
 *         the message has them. */
void imu_wire_gnss_fix(const imu_proto_gnss_t *msg, imu_navfilter_gnss_t *fix);

#ifdef IMU_FIXED
/**
 * @brief The ESTIMATE of filter `f` after sample `index` (the message carries the fixed
 *        build's integers): `out`, the attitude and gyro bias imu_filter_get() gave after that
 *        sample (the caller takes it, so that the board can time the update and the get
 *        together), the filter's saturations, and the ESKF's covariance diagonal and
 *        measurement weights (zeros for the other kinds).
 */
void imu_wire_estimate(const imu_filter_t *f, const imu_output_t *out, uint32_t index, imu_proto_estimate_t *msg);

/** @brief The nav filter's state as the NAV_STATE message carries it, after sample `index`. */
void imu_wire_nav_state(const imu_navfilter_t *f, uint32_t index, imu_proto_nav_state_t *msg);
#endif

#endif /* IMU_WIRE_H */
