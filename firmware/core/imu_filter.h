/**
 * @file imu_filter.h
 * @brief One handle for every filter: select by id, feed raw samples, read outputs.
 *
 * This is what the firmware main loop and the host bindings use; each filter's
 * own header documents its settings and behaviour.
 */
#ifndef IMU_FILTER_H
#define IMU_FILTER_H

#include "imu_common.h"
#include "imu_eecf.h"
#include "imu_eskf.h"
#include "imu_kf1d.h"
#include "imu_navfilter.h"
#include "imu_sensor.h"

/** Filter identifiers (stable: they travel in the frame protocol). */
typedef enum {
    IMU_FILTER_EECF = 1,
    IMU_FILTER_KF1D = 2,
    IMU_FILTER_ESKF = 3,
    IMU_FILTER_NAV = 4, /**< navigation (imu_navfilter.h): position and velocity besides the attitude */
} imu_filter_id_t;

/** Room for the settings struct of any kind (each kind reads its own member). */
typedef union {
    imu_eecf_settings_t eecf;
    imu_kf1d_settings_t kf1d;
    imu_eskf_settings_t eskf;
    imu_navfilter_settings_t nav;
} imu_filter_settings_t;

/**
 * One kind of filter: everything the dispatch, the board and the host need to know of it.
 * The functions take the kind's own state (the member of imu_filter_t.u) and settings
 * struct as void *, so that one table serves every kind.
 */
typedef struct {
    imu_filter_id_t id;
    const char *name;                /**< the host's name of it: "eecf", "kf1d", "eskf", "nav" */
    const imu_setting_desc_t *descs; /**< its settings; field 0 is every kind's sample_rate, Hz, Q16 */
    const int *setting_count;        /**< entries of descs (the count is defined in the kind's own file,
                                          so only its address is a constant here) */
    const void *defaults;            /**< its default settings struct */
    size_t settings_size;            /**< sizeof its settings struct, bytes */
    size_t conversion_saturations;   /**< offsetof the uint32_t in its state that counts the
                                          saturations of the count conversion */
    size_t state_size;               /**< sizeof its state struct, bytes (a checkpoint's size) */
    void (*init)(void *state);
    imu_status_t (*set_settings)(void *state, const void *settings);
    void (*update)(void *state, const imu_sample_t *sample);
    void (*get)(const void *state, imu_output_t *out);
    uint32_t (*saturations)(const void *state); /**< every saturation since the (re)start */
} imu_filter_kind_t;

/** Entries of imu_filter_kinds. */
#define IMU_FILTER_KIND_COUNT 4

/** Every kind, in the order of their ids. */
extern const imu_filter_kind_t imu_filter_kinds[IMU_FILTER_KIND_COUNT];

/** @brief The kind with identifier `id`, NULL for an unknown id. */
const imu_filter_kind_t *imu_filter_kind(int id);

/** A filter of any kind. All members are private. */
typedef struct {
    imu_filter_id_t id;
    const imu_filter_kind_t *kind; /**< the entry of imu_filter_kinds for id */
    imu_sensor_settings_t sensor;
    imu_calibration_t calibration;
    int calibrated;            /**< 0 while the calibration is the identity: the counts are scaled as they are */
    union {
        imu_eecf_t eecf;
        imu_kf1d_t kf1d;
        imu_eskf_t eskf;
        imu_navfilter_t nav;
    } u;
} imu_filter_t;

/** @brief Initialise filter `id` with default settings; IMU_ERR_UNKNOWN for an unknown id. */
imu_status_t imu_filter_init(imu_filter_t *f, int id);

/** @brief Apply the filter's settings struct (the type matching its id) and restart it;
 *         IMU_ERR_RANGE (and nothing changed) when a field is out of its range. */
imu_status_t imu_filter_set_settings(imu_filter_t *f, const void *settings);

/** @brief Set the sensor sensitivities. */
void imu_filter_set_sensor(imu_filter_t *f, const imu_sensor_settings_t *sensor);

/** @brief Set the calibration applied to the counts before the filter (imu_sensor.h);
 *         IMU_ERR_RANGE (and nothing changed) unless imu_calibration_check() accepts it.
 *         imu_filter_init() sets imu_calibration_identity. */
imu_status_t imu_filter_set_calibration(imu_filter_t *f, const imu_calibration_t *cal);

/** @brief Calibrate and convert one raw sample and update the filter. */
void imu_filter_update_raw(imu_filter_t *f, const imu_raw_sample_t *raw);

/** @brief The same for one sample's counts given as three x, y, z triples (rows of count arrays). */
void imu_filter_update_counts(imu_filter_t *f, const int16_t gyr[3], const int16_t acc[3], const int16_t mag[3]);

/** @brief Current estimate. */
void imu_filter_get(const imu_filter_t *f, imu_output_t *out);

/** @brief Saturation events counted since the last (re)start. */
uint32_t imu_filter_saturations(const imu_filter_t *f);

/**
 * @brief The active filter's state as bytes (imu_filter_state_size() of them): everything its
 *        next update depends on besides the sensor scales and the calibration (settings, attitude,
 *        biases, covariance, buffers, detectors). A checkpoint: CHECKPOINT frames carry it.
 *
 * The bytes are the kind's state struct as it lies in memory. The state structs hold fixed-width
 * integers only and no implicit padding (tests/test_c_build.py compiles them with -Wpadded), so
 * the bytes are all defined and lie the same way on every little-endian target that aligns a
 * 64-bit integer to 8 bytes (the Cortex-M4's AAPCS, x86-64): a board's checkpoint restores in the
 * host build.
 */
const uint8_t *imu_filter_state(const imu_filter_t *f);

/** @brief Bytes of the active filter's state (imu_filter_state). */
size_t imu_filter_state_size(const imu_filter_t *f);

/** @brief Put back a state imu_filter_state gave (of the same filter kind, with the same settings):
 *         IMU_ERR_RANGE, and nothing changed, when `size` is not the kind's state size. */
imu_status_t imu_filter_restore(imu_filter_t *f, const uint8_t *state, size_t size);

/** @brief The ESKF state of a filter handle (for its covariance and accelerometer bias), NULL for another filter. */
const imu_eskf_t *imu_filter_eskf(const imu_filter_t *f);

/** @brief The nav filter of a handle (for its fixes, barometer and state), NULL for another filter. */
imu_navfilter_t *imu_filter_nav(imu_filter_t *f);

/**
 * @brief Run n samples (int16 counts, n x 3 arrays row-major) and store each output.
 * @param quat      n x 4 output, Q30 (may be NULL)
 * @param euler     n x 3 output, Q29 rad (may be NULL)
 * @param gyro_bias n x 3 output, Q24 rad/s (may be NULL)
 */
void imu_filter_run(imu_filter_t *f, const int16_t *gyr, const int16_t *acc, const int16_t *mag, size_t n,
                    imu_q30_t *quat, imu_angle_t *euler, imu_rate_t *gyro_bias);

#endif /* IMU_FILTER_H */
