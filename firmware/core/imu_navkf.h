/**
 * @file imu_navkf.h
 * @brief The `nav` filter: loosely coupled GNSS/INS navigation, a 16-state error-state
 *        Kalman filter around the strapdown propagation of imu_nav.h ([seed 002], sections 4
 *        and 5), with zero-velocity updates at rest and position fixes from any source
 *        ([seed 003]'s markers; sources: docs/filters.md, Bibliography).
 *
 * Error state (the covariance's states, each block in a unit of its own so that every
 * innovation, correction and transition entry is a Q30 value below 2):
 *
 * | states | what | unit |
 * |---|---|---|
 * | 0-2   | position error, east north up | 1024 m |
 * | 3-5   | velocity error, ENU | 64 m/s |
 * | 6-8   | attitude error, sensor frame (true = estimate turned by it) | rad |
 * | 9-11  | gyroscope bias error | rad/s |
 * | 12-14 | accelerometer bias error | m/s^2 |
 * | 15    | barometer bias error (its height minus the true one) | 1024 m |
 *
 * The covariance (imu_navcov.h, block-floating: its variances span fourteen decades) is
 * propagated every `cov_steps` samples (about 20 Hz) with the interval's transition,
 * built from the attitude at its start and end and the specific force integrated over
 * it, applied as three factors of three moving rows each (position, then velocity, then
 * attitude: each factor reads only states the earlier ones left alone, so their product
 * is the transition). A measurement first brings the covariance up to the sample.
 *
 * Measurements: the barometer's height (with a bias state: the weather moves it); GNSS
 * position and velocity of the antenna (a lever arm from the sensor) with the receiver's
 * accuracies, back to the time the fix was valid for by the estimated velocity and
 * acceleration (a receiver's latency: tenths of a second), gated by the normalised
 * innovation, position and velocity apart (a multipath jump is rejected and counted, while
 * dead reckoning lets the covariance grow, until the fixes agree again; a fix that agrees
 * with the last one used but not with the estimate scales the covariance up; a run of
 * rejected fixes that agree with each other for `reset_time` resets position and velocity
 * to the fixes, as the estimate is then the one in doubt); position fixes with an
 * accuracy (markers: not gated). At rest (the bias-corrected rate and the specific force
 * still for `rest_steps`; with GNSS, only while the last fix said the board stood,
 * weighted by how steady the force is, through an outage too; after a minute without
 * GNSS, or from a start without it, on the sensors alone), zero velocity and zero rate
 * (the gyroscope reads its bias). The magnetometer's heading every interval, at any speed
 * (left out: a field whose strength or dip is off, a heading beyond 3 standard deviations
 * of the estimate's, a field that turns against the gyroscope); without GNSS the
 * accelerometer's tilt too (the attitude kept as an attitude filter keeps it).
 *
 * Fixed build formats are written where each value is declared; the float build holds the
 * same quantities in the same units (one source).
 */
#ifndef IMU_NAVKF_H
#define IMU_NAVKF_H

#include "imu_math.h"
#include "imu_nav.h"
#include "imu_navcov.h"

/** Number of error states. */
#define IMU_NAVKF_STATES 16

/** Where a fix comes from. */
typedef enum {
    IMU_NAVKF_GNSS = 0,  /**< a receiver: gated, and its speed tells whether the board stands */
    IMU_NAVKF_MARKER = 1 /**< a known place ([seed 003]'s markers): trusted as its accuracy says */
} imu_navkf_source_t;

/**
 * What a mount and a receiver call for (the board's nav settings, imu_navfilter.h), in the
 * units and Q formats given: the process noise (white densities as the filter takes them,
 * about twice a data sheet's for the quantisation and what the model leaves out; the biases'
 * random walks), the gate, how long a run of rejected fixes that agree with each other lasts
 * before the estimate is the one in doubt, and the rest detector's bounds. The ranges are
 * the board's settings' (imu_navfilter.c); the noise's upper bounds keep a covariance
 * interval's process noise (density^2 * 0.25 s at most, Q54 * Q30) within int64.
 */
typedef struct {
    imu_real_t gyro_noise;     /**< rad/s/sqrt(Hz), Q30, [1e-5, 1e-3] */
    imu_real_t acc_noise;      /**< m/s^2/sqrt(Hz), Q30, [1e-4, 0.08] */
    imu_real_t gyro_bias_walk; /**< rad/s/sqrt(s), Q30, [1e-7, 1e-3] */
    imu_real_t acc_bias_walk;  /**< m/s^2/sqrt(s), Q30, [1e-6, 1e-3] */
    imu_real_t gate;           /**< chi-square bound of a fix's position, and of its velocity, Q16, [7.81, 100] */
    imu_real_t reset_time;     /**< s, Q16, [1, 600] */
    imu_real_t rest_rate;      /**< the bias-corrected rate's bound at rest, rad/s, Q24, [0.005, 1] */
    imu_real_t rest_force;     /**< the specific force's distance from gravity at rest, m/s^2, Q16, [0.02, 3] */
    imu_real_t acc_range;      /**< the accelerometer's full scale (a sample at it clipped), m/s^2, Q16, [19.6, 200] */
} imu_navkf_tuning_t;

/** The defaults, as an initializer: twice the MPU6050 data sheet's white noise (0.005
 *  deg/s/sqrt(Hz), 400 ug/sqrt(Hz)), bias walks of 1e-5 rad/s/sqrt(s) and 1e-4
 *  m/s^2/sqrt(s), chi-square at 99.9 % for three degrees of freedom, 15 s, 0.05 rad/s and
 *  0.3 m/s^2, the MPU6050's +-8 g (the GY-86 profile's): one set that serves a car, a
 *  drone, a handheld device and a foot mount (docs/navigation.md). */
#define IMU_NAVKF_DEFAULT_TUNING                                                              \
    {                                                                                         \
        IMU_QCONST(1.7453293e-4, 30), IMU_QCONST(7.845320e-3, 30), IMU_QCONST(1e-5, 30),     \
            IMU_QCONST(1e-4, 30), IMU_QCONST(16.27, 16), IMU_QCONST(15.0, 16),                \
            IMU_QCONST(0.05, 24), IMU_QCONST(0.3, 16), IMU_QCONST(78.4532, 16)                \
    }

/** A GNSS fix, or a position fix from another source (without velocity). */
typedef struct {
    int source;         /**< imu_navkf_source_t */
    imu_angle_t lat;    /**< rad, Q29 */
    imu_angle_t lon;    /**< rad, Q29 */
    imu_real_t height;  /**< mm above the ellipsoid */
    imu_real_t vel[3];  /**< ENU, m/s, Q20 (used when has_vel) */
    int has_vel;        /**< 0: a position-only fix */
    imu_real_t h_acc;   /**< horizontal accuracy (1 sigma of the distance), mm, 1 .. 2^30 */
    imu_real_t v_acc;   /**< vertical accuracy, mm, 1 .. 2^30 */
    imu_real_t s_acc;   /**< speed accuracy (each axis), mm/s, 1 .. 2^30 */
    imu_q30_t age;      /**< how long ago the fix was valid, s, Q30, [0, 1] */
} imu_navkf_fix_t;

typedef struct {
    imu_nav_t nav;              /**< the strapdown state */
    imu_navcov_t cov;           /**< error-state covariance, the units above */
    imu_q30_t q_start[4];       /**< attitude at the start of the covariance interval, Q30 */
    int32_t padding_dv;          /**< explicit padding: a state has none implicit, so a checkpoint's bytes are all defined (docs/protocol.md) */
    imu_wide_t dv[3];           /**< specific force (ENU) times dt summed over the interval, in units of 64 m/s, Q52 */
    int32_t steps;              /**< samples in the interval so far */
    imu_real_t lever_arm[3];    /**< the GNSS antenna's position in the sensor frame, m, Q20 (within +-10 m) */
    imu_rate_t rate[3];         /**< the last sample's bias-corrected rate, rad/s, Q24 */
    int32_t padding_carry;       /**< explicit padding: a state has none implicit, so a checkpoint's bytes are all defined (docs/protocol.md) */
    imu_wide_t carry[IMU_NAVKF_STATES]; /**< the corrections' rounding, carried to the next (velocity: Q54 of
                                             m/s; biases: Q30; 0 elsewhere and in the float build) */
    int32_t cov_steps;          /**< samples per covariance interval */
    imu_real_t sample_rate;     /**< Hz, Q16 */
    imu_q30_t dt_per_64;        /**< sample interval / 64, s, Q36 (dv's factor) */
    int32_t still;              /**< consecutive still samples (stops counting at rest_steps) */
    int32_t rest_steps;         /**< still samples that make rest */
    int32_t padding_zero_rate_var; /**< explicit padding: a state has none implicit, so a checkpoint's bytes are all defined (docs/protocol.md) */
    imu_wide_t zero_rate_var;   /**< variance of one sample's rate at rest, (rad/s)^2, Q60 */
    int32_t longest_steps;      /**< where the counts stop: a minute (without GNSS that long, rest is the sensors') */
    imu_q16_t force_fast[3];    /**< the specific force low-passed over 0.1 s, sensor frame, m/s^2, Q16 */
    imu_q16_t force_slow[3];    /**< ... over 1 s */
    imu_q30_t fast_weight;      /**< their weights per sample, dt / tau, Q30 */
    imu_q30_t slow_weight;
    int32_t since_fix;          /**< samples since the last GNSS fix, used or not (stops counting at a minute) */
    int fix_stood;              /**< 1 when the last GNSS fix's speed was below REST_SPEED (0: no velocity) */
    imu_real_t field_reference; /**< the field's strength at the start, the mag's unit (0: none) */
    imu_angle_t dip_reference;  /**< its dip in the estimate's frame (the mean of those seen), rad, Q29 */
    int32_t dips_seen;          /**< how many that mean is over (stops counting at DIP_MEMORY) */
    imu_angle_t field_apart;    /**< the field's heading turned against the estimate's (what the gyroscope did not
                                     see), summed over the intervals, minus that sum's low-pass over 2 s; as
                                     sines, Q29 */
    imu_angle_t field_away;     /**< while the field is left out for turning: how far it is from where it was, Q29 */
    imu_angle_t field_after;    /**< the last interval's field heading against the estimate's, as a sine, Q29,
                                     moved by the corrections since */
    imu_real_t field_north;     /**< the field's north over its horizontal component, Q29 (a correction's effect) */
    imu_real_t field_up;        /**< its up over its horizontal component, Q24 */
    int32_t field_turned;       /**< 1 while the field is left out for turning (0: not; -1: no heading yet) */
    imu_field_trust_t field_trust; /**< intervals the field held, and the turned field has been held out */
    int32_t doubting;           /**< samples since the first of the current run of rejected GNSS fixes that agree
                                     with each other; -1: none */
    int32_t reset_steps;        /**< samples of such a run after which position and velocity are reset to the fixes */
    imu_navkf_tuning_t tuning;  /**< imu_navkf_tune's (the defaults from imu_navkf_start) */
    int32_t padding_noise_vel;   /**< explicit padding: a state has none implicit, so a checkpoint's bytes are all defined (docs/protocol.md) */
    imu_wide_t noise_vel;       /**< process noise per second from the tuning, Q54 of (64 m/s)^2 */
    imu_wide_t noise_att;       /**< ... rad^2 */
    imu_wide_t noise_gyro_bias; /**< ... (rad/s)^2 */
    imu_wide_t noise_acc_bias;  /**< ... (m/s^2)^2 */
    imu_q16_t clip_level;       /**< a specific force at or beyond this on an axis is clipped, m/s^2, Q16 */
    int32_t padding_clip_var;    /**< explicit padding: a state has none implicit, so a checkpoint's bytes are all defined (docs/protocol.md) */
    imu_wide_t clip_var;        /**< velocity variance per clipped sample, Q60 of (64 m/s)^2 */
    imu_wide_t clipped_var;     /**< ... summed over the covariance interval so far */
    int32_t gap_steps;          /**< two fixes further apart than this (samples) are not compared */
    imu_real_t last_offset[3];  /**< the last GNSS fix's offset from the estimate then (antenna's, ENU), mm */
    imu_real_t last_at[3];      /**< its position in the origin's offsets (imu_nav_offsets), mm */
    imu_real_t last_vel[3];     /**< its velocity, m/s, Q20 */
    int last_fix;               /**< 0: none to compare with; 1: a position; 2: with velocity */
    int last_used;              /**< 1 when its position was used */
    imu_real_t moved[3];        /**< the position corrections applied since the last GNSS fix, ENU, mm */
    imu_real_t spread;          /**< how far consecutive fixes disagree beside their accuracy, a running mean
                                     of their normalised horizontal disagreement, Q16 (RAYLEIGH_MEAN: as
                                     reported) */
    uint32_t rejected;          /**< GNSS fixes rejected by the gate (position or velocity), in all */
    uint32_t resets;            /**< position and velocity reset to the fixes (the filter's own divergence) */
    uint32_t fades;             /**< fixes that scaled the covariance up (the estimate in doubt) */
    uint32_t zero_velocity;     /**< zero-velocity (and zero-rate) updates, in all */
    imu_real_t baro_bias;       /**< the barometer's height minus the true one, mm */
    imu_real_t baro_reference;  /**< pressure of the barometer's reference, Pa (0: none yet) */
    imu_real_t baro_reference_height; /**< the reference's height, mm */
    int32_t baro_steps;         /**< samples between barometer updates */
    int32_t since_baro;         /**< samples since the last (stops counting at baro_steps) */
    int anchored;               /**< 0 until a fix gave the position (a start without one) */
} imu_navkf_t;

/**
 * @brief Start at rest: attitude from the accelerometer (tilt) and the magnetometer
 *        (heading), position from `fix` (its origin too), velocity from the fix's when it
 *        has one, else zero.
 * @param rate sample rate, Hz, Q16, 10 .. 1000
 * @param acc  specific force, m/s^2, Q16; @param mag field, any unit (Q16 uT on the wire)
 * @param lever_arm the GNSS antenna's position in the sensor frame (x right, y forward, z up),
 *        mm, each axis within +-10 m, or NULL: at the sensor. The fixes are the antenna's.
 * @return IMU_ERR_RANGE for a rate, fix or lever arm out of range, or an accelerometer that
 *         reads nothing.
 */
imu_status_t imu_navkf_start(imu_navkf_t *f, imu_real_t rate, const imu_q16_t acc[3], const imu_real_t mag[3],
                             const imu_navkf_fix_t *fix, const imu_real_t lever_arm[3]);

/**
 * @brief Tune a started filter (before its first sample): IMU_ERR_RANGE, and nothing changed,
 *        for a value that is not positive (the board's settings check their ranges first).
 */
imu_status_t imu_navkf_tune(imu_navkf_t *f, const imu_navkf_tuning_t *tuning);

/**
 * @brief One IMU sample: propagation, and at the end of an interval the covariance, at rest
 *        zero velocity and zero rate, the magnetometer's heading and without GNSS the
 *        accelerometer's tilt.
 * @param gyr rad/s, Q24; @param acc specific force, m/s^2, Q16
 * @param mag field in the sensor frame, any unit (Q16 uT on the wire), or NULL / zero: none
 */
void imu_navkf_step(imu_navkf_t *f, const imu_rate_t gyr[3], const imu_q16_t acc[3], const imu_real_t mag[3]);

/** @brief A GNSS fix, or a position fix (has_vel 0). @return 1 when used; 0 when the gate rejected it
 *         (counted in `rejected`) or an accuracy is out of its range (not counted). */
int imu_navkf_fix(imu_navkf_t *f, const imu_navkf_fix_t *fix);

/**
 * @brief A barometer sample: its pressure (Pa; an MS5611's compensated value) gives a
 *        height against a reference taken at the first sample; at most one update a second
 *        (height and the barometer's bias, which follows the weather).
 */
void imu_navkf_baro(imu_navkf_t *f, imu_real_t pressure);

/** @brief Position: latitude, longitude (rad, Q29) and height (mm). */
void imu_navkf_position(const imu_navkf_t *f, imu_angle_t *lat, imu_angle_t *lon, imu_real_t *height);

/** @brief Variance of error state i (table above) as P_ii = mant 2^(exp - 30) in (its unit)^2;
 *         float build: mant = P_ii, exp = 0. */
void imu_navkf_variance(const imu_navkf_t *f, int i, imu_real_t *mant, int32_t *exp);

#endif /* IMU_NAVKF_H */
