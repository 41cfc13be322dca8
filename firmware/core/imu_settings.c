/**
 * @file imu_settings.c
 * @brief The range check of a filter's settings against its descriptor table.
 */
#include "imu_common.h"

imu_status_t imu_settings_check(const imu_setting_desc_t descs[], int count, const void *settings)
{
    int i;
    for (i = 0; i < count; ++i) {
        const imu_real_t *value = (const imu_real_t *)(const void *)((const char *)settings + descs[i].offset);
        if (!(*value >= descs[i].min && *value <= descs[i].max)) { /* written so that a NaN fails too */
            return IMU_ERR_RANGE;
        }
    }
    return IMU_OK;
}
