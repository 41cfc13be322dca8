/**
 * @file imu_common.h
 * @brief Types shared by every filter: the output record, status codes and the
 *        settings descriptors that let a host read and write settings by name.
 */
#ifndef IMU_COMMON_H
#define IMU_COMMON_H

#include <stddef.h>

#include "imu_arith.h"

/** Result of calls that validate their input. */
typedef enum {
    IMU_OK = 0,
    IMU_ERR_RANGE = -1,   /**< a setting is outside its documented range */
    IMU_ERR_UNKNOWN = -2, /**< unknown filter or setting */
} imu_status_t;

/** What every filter reports after each update. */
typedef struct {
    imu_q30_t quat[4];      /**< sensor-to-earth (ENU) quaternion, w first, Q30 */
    imu_angle_t euler[3];   /**< [roll, pitch, heading] in rad, Q29 (see imu_math.h) */
    imu_rate_t gyro_bias[3]; /**< estimated gyroscope bias per sensor axis, rad/s, Q24 */
} imu_output_t;

/**
 * Description of one settings field. Every settings field is an imu_real_t:
 * an int32 holding a real in Q`frac_bits` in the fixed build, a double in the
 * float build. The range [min, max] is the one each filter's set_settings call
 * accepts (imu_settings_check); it travels to the host in the SETTING message, so
 * this table is its only definition.
 */
typedef struct {
    const char *name;   /**< field name, as in the C struct */
    size_t offset;      /**< offsetof() in the settings struct */
    int frac_bits;      /**< Q format of the field in the fixed build */
    const char *unit;   /**< SI unit of the value */
    imu_real_t min;     /**< smallest accepted value, Q`frac_bits` (an open bound "> 0" is the format's smallest step) */
    imu_real_t max;     /**< largest accepted value, Q`frac_bits` */
} imu_setting_desc_t;

/** Range ends written in real units (for IMU_QCONST): the largest Q16 value, 2^15 - 2^-16
 *  (a closed bound for "below 32768"), and the smallest positive Q24 value, 2^-24 (an open
 *  bound "> 0"). */
#define IMU_Q16_LARGEST 32767.9999847412109375
#define IMU_Q24_SMALLEST 5.9604644775390625e-08

/** @brief IMU_OK when every field of `settings` (a filter's settings struct) lies in its
 *         descriptor's [min, max], else IMU_ERR_RANGE. */
imu_status_t imu_settings_check(const imu_setting_desc_t descs[], int count, const void *settings);

#endif /* IMU_COMMON_H */
