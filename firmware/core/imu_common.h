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
 * float build. Ranges are checked by each filter's SetSettings call.
 */
typedef struct {
    const char *name;   /**< field name, as in the C struct */
    size_t offset;      /**< offsetof() in the settings struct */
    int frac_bits;      /**< Q format of the field in the fixed build */
    const char *unit;   /**< SI unit of the value */
} imu_setting_desc_t;

#endif /* IMU_COMMON_H */
