/**
 * @file imu_nav.h
 * @brief Strapdown navigation: attitude, velocity and position from the gyroscope and the
 *        accelerometer, on the WGS-84 ellipsoid (the propagation of the `nav` filter,
 *        imu_navkf.h).
 *
 * Frames and conventions as everywhere in imulink: the local level frame is east, north,
 * up (ENU) at the current position, the quaternion turns sensor vectors into it (w first),
 * the accelerometer reads specific force. The Earth's rotation is left out (a MEMS
 * gyroscope's noise is larger; the simulator's trajectories leave it out too).
 *
 * Position: the origin's geodetic latitude and longitude (rad, Q29) and height (mm), and
 * curvilinear offsets from it in mm: north = (lat - lat0) (M0 + h0) and east = (lon - lon0)
 * (N0 + h0) cos(lat0), M and N the meridian and prime-vertical radii of curvature (0 at
 * the origin). The offsets are latitude and longitude scaled by constants, so the
 * position stays geodetic however far the board travels (a tangent plane at the origin
 * leaves the vertical behind: 1 mrad per 6.4 km), and in int32 mm they cover
 * +-2 147 km at 1 mm (the requirement: +-100 km at 1 mm or better). Each step moves them
 * by the step's metres times (M0 + h0) / (M + h) and ((N0 + h0) cos lat0) / ((N + h) cos
 * lat); the rounding of every step is carried to the next (error feedback), so slow
 * motion at a high rate adds up exactly.
 *
 * Fixed build formats are written where each value is declared; the float build holds the
 * same quantities as doubles in the same units (one source).
 */
#ifndef IMU_NAV_H
#define IMU_NAV_H

#include "imu_common.h"

/** Geodetic origin of the position offsets. */
typedef struct {
    imu_angle_t lat;   /**< latitude, rad, Q29, within +-85 deg */
    imu_angle_t lon;   /**< longitude, rad, Q29, [-pi, pi] */
    imu_real_t height; /**< height above the ellipsoid, mm (fixed: integer), +-10 km */
} imu_nav_origin_t;

/** Largest speed the state holds, m/s (a step then stays below 2^16 mm at 10 Hz). */
#define IMU_NAV_MAX_SPEED 512.0

typedef struct {
    imu_nav_origin_t origin;
    imu_q30_t origin_rm;        /**< (M0 + h0) / a, Q30 (a: the ellipsoid's semi-major axis) */
    imu_q30_t origin_rn_cos;    /**< (N0 + h0) cos(lat0) / a, Q30 */
    imu_real_t lat_per_mm;      /**< rad of latitude per mm of north offset, Q59 */
    imu_real_t lon_per_mm;      /**< rad of longitude per mm of east offset, Q59 (below 2^31 within +-85 deg) */
    imu_q30_t dt;               /**< sample interval, s, Q30 */
    imu_q30_t q[4];             /**< attitude, sensor to ENU, Q30 */
    imu_real_t vel[3];          /**< velocity, ENU, m/s, Q20 (|v| <= IMU_NAV_MAX_SPEED) */
    imu_real_t pos[3];          /**< east and north offsets from the origin, height above it, mm */
    imu_rate_t gyro_bias[3];    /**< subtracted from the gyroscope, rad/s, Q24 */
    imu_q16_t acc_bias[3];      /**< subtracted from the accelerometer, m/s^2, Q16 */
    imu_wide_t vel_carry[3];    /**< rounding carried between velocity steps, Q46 */
    imu_wide_t pos_carry[3];    /**< rounding carried between position steps: Q45 (east, north), Q15 (up) mm */
    imu_q30_t scale_east;       /**< ((N0 + h0) cos lat0) / ((N + h) cos lat), Q30 */
    imu_q30_t scale_north;      /**< (M0 + h0) / (M + h), Q30 */
    imu_real_t gravity;         /**< normal gravity at the position, m/s^2, Q24 */
    imu_q16_t acc[3];           /**< the last step's acceleration, ENU, m/s^2, Q16 (gravity removed) */
    imu_q30_t theta_prev[3];    /**< the last sample's angle increment (bias-corrected), rad, Q30 */
    imu_q16_t force_prev[3];    /**< the last sample's specific force (bias-corrected), sensor frame, m/s^2, Q16 */
    uint32_t saturations;       /**< clamped intermediate results (0 in normal operation) */
    uint32_t padding;           /**< explicit padding: a state has none implicit, so a checkpoint's bytes are all defined (docs/protocol.md) */
} imu_nav_t;

/**
 * @brief Start at the origin (offsets zero) with an attitude and a velocity.
 * @param rate sample rate, Hz, Q16, 10 .. 32768
 * @param vel  ENU velocity, m/s, Q20
 * @return IMU_ERR_RANGE for a rate, origin or velocity out of range (nothing changed), else IMU_OK.
 */
imu_status_t imu_nav_start(imu_nav_t *n, const imu_nav_origin_t *origin, imu_real_t rate, const imu_q30_t q[4],
                           const imu_real_t vel[3]);

/**
 * @brief Move the origin to another place, the position onto it (offsets zero); the
 *        attitude, velocity and biases stay.
 * @return IMU_ERR_RANGE for an origin out of range (nothing changed), else IMU_OK.
 */
imu_status_t imu_nav_anchor(imu_nav_t *n, const imu_nav_origin_t *origin);

/**
 * @brief One sample: the attitude turned by the gyroscope, the velocity and the position
 *        moved by the specific force and normal gravity.
 * @param gyr angular rate, rad/s, Q24
 * @param acc specific force averaged over the sample interval in the turning sensor frame
 *            (what a MEMS accelerometer's low-pass delivers), m/s^2, Q16
 */
void imu_nav_propagate(imu_nav_t *n, const imu_rate_t gyr[3], const imu_q16_t acc[3]);

/**
 * @brief Curvilinear offsets (east, north, up; mm, the units of `pos`) of a geodetic point
 *        from the origin: what `pos` would be there. Saturated (counted) beyond int32.
 * @param lat rad, Q29; @param lon rad, Q29; @param height mm above the ellipsoid
 */
void imu_nav_offsets(imu_nav_t *n, imu_angle_t lat, imu_angle_t lon, imu_real_t height, imu_real_t out[3]);

/**
 * @brief Move the position by a displacement in the local level frame (east, north, up),
 *        mm, Q15 each (wide: a correction), with the rounding carried as the steps' is.
 */
void imu_nav_move(imu_nav_t *n, const imu_wide_t step[3]);

/** @brief Latitude of the position, rad, Q29. */
imu_angle_t imu_nav_latitude(const imu_nav_t *n);

#endif /* IMU_NAV_H */
