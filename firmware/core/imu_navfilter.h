/**
 * @file imu_navfilter.h
 * @brief The `nav` filter as the board runs it (imu_filter.h's IMU_FILTER_NAV): the
 *        navigation filter of imu_navkf.h fed with the board's converted samples, its
 *        receiver's fixes in the receiver's units (imu_wire.h makes them of the GNSS
 *        message), markers and the barometer's pressure, with settings like the attitude
 *        filters'.
 *
 * It starts at its first sample whose accelerometer reads a force, with the attitude from
 * the accelerometer and the magnetometer and no position: the attitude is there at once, as
 * an attitude filter's, and the first usable fix (a 3-D GNSS fix within the receiver's
 * masks, or a marker) gives the position and the velocity.
 */
#ifndef IMU_NAVFILTER_H
#define IMU_NAVFILTER_H

#include "imu_common.h"
#include "imu_navkf.h"
#include "imu_sensor.h"

/** Settings. All fields are imu_real_t: Q format in the fixed build as written.
 *  New fields are appended, so the indices of the older ones stay. */
typedef struct {
    imu_real_t sample_rate;  /**< Hz, Q16, [10, 1000] */
    imu_real_t lever_arm_x;  /**< the GNSS antenna's position in the sensor frame (x right), m, Q16, [-10, 10] */
    imu_real_t lever_arm_y;  /**< ... y forward, m, Q16, [-10, 10] */
    imu_real_t lever_arm_z;  /**< ... z up, m, Q16, [-10, 10] */
    imu_real_t gnss_latency; /**< how long before its arrival a fix was valid, s, Q16, [0, 1] */
    imu_navkf_tuning_t tuning; /**< noise densities, the gate, the reset time, the rest bounds (ranges in
                                    imu_navfilter_setting_descs) */
} imu_navfilter_settings_t;

extern const imu_navfilter_settings_t imu_navfilter_default_settings;
extern const imu_setting_desc_t imu_navfilter_setting_descs[];
extern const int imu_navfilter_setting_count;

/** A receiver's fix in the receiver's units (u-blox NAV-PVT's; an NMEA receiver's are
 *  converted to them), kept so that the filter does the conversions and counts their
 *  saturations. */
typedef struct {
    int usable;              /**< 1: a 3-D fix within the receiver's accuracy masks; 0: not to be used */
    int32_t lat_1e7deg;      /**< latitude, 1e-7 deg */
    int32_t lon_1e7deg;      /**< longitude, 1e-7 deg */
    int32_t height_mm;       /**< height above the WGS-84 ellipsoid, mm */
    int has_velocity;        /**< 1: vel_ned_mm_s and s_acc_mm_s are measured */
    int32_t vel_ned_mm_s[3]; /**< velocity north, east, down, mm/s */
    uint32_t h_acc_mm;       /**< horizontal accuracy, mm (0: not given) */
    uint32_t v_acc_mm;       /**< vertical accuracy, mm (0: not given) */
    uint32_t s_acc_mm_s;     /**< speed accuracy, mm/s (0: not given) */
} imu_navfilter_gnss_t;

/** State. All members are private. */
typedef struct {
    imu_navfilter_settings_t settings;
    imu_navkf_t kf;
    int started;           /**< 0 until a sample's accelerometer read a force (kf is not started) */
    uint32_t saturations;  /**< saturations converting the samples (the filter's own are kf's) */
} imu_navfilter_t;

/** @brief Default settings, not started. */
void imu_navfilter_init(imu_navfilter_t *f);

/** @brief Apply settings (IMU_ERR_RANGE and nothing changed when one is out of its range) and start again. */
imu_status_t imu_navfilter_set_settings(imu_navfilter_t *f, const imu_navfilter_settings_t *settings);

/** @brief One converted sample (imu_sample_from_raw_calibrated). */
void imu_navfilter_update(imu_navfilter_t *f, const imu_sample_t *sample);

/**
 * @brief A receiver's fix, after the sample it arrived with: used when fix->usable;
 *        accuracies of 0 (not given: NMEA) are taken as a consumer receiver's, 5 m
 *        horizontal, 10 m vertical, 0.5 m/s.
 * @return 1 when the filter used it, 0 otherwise (not usable, gated, or before the start).
 */
int imu_navfilter_gnss(imu_navfilter_t *f, const imu_navfilter_gnss_t *fix);

/**
 * @brief A position fix from a known place ([seed 003]'s markers: docs/filters.md, Bibliography), trusted as its accuracy says.
 * @param lat_1e7deg, lon_1e7deg 1e-7 deg; @param height_mm above the ellipsoid
 * @param h_acc_mm, v_acc_mm accuracies, 1 .. 2^30 mm
 * @return 1 when used, 0 when out of range or before the start.
 */
int imu_navfilter_marker(imu_navfilter_t *f, int32_t lat_1e7deg, int32_t lon_1e7deg, int32_t height_mm,
                         uint32_t h_acc_mm, uint32_t v_acc_mm);

/** @brief The barometer's compensated pressure, Pa, after the sample it was read with. */
void imu_navfilter_baro(imu_navfilter_t *f, int32_t pressure_pa);

/** @brief Attitude (identity before the start), Euler angles and gyroscope bias. */
void imu_navfilter_get(const imu_navfilter_t *f, imu_output_t *out);

/** @brief Saturation events since the settings were applied. */
uint32_t imu_navfilter_saturations(const imu_navfilter_t *f);

/** @brief The navigation state (imu_navkf.h), NULL before the start. */
const imu_navkf_t *imu_navfilter_state(const imu_navfilter_t *f);

#endif /* IMU_NAVFILTER_H */
