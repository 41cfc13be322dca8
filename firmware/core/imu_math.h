/**
 * @file imu_math.h
 * @brief Vector, quaternion and angle helpers on the arithmetic layer's types.
 *
 * Conventions: quaternions are w-first, sensor-to-earth, earth frame ENU; the
 * sensor (body) frame has x to the right, y forward, z up ([seed 000] and [seed 004]:
 * docs/filters.md, Bibliography).
 * Euler angles are [roll, pitch, heading] in rad with R = Rz(-heading) Rx(pitch)
 * Ry(roll): pitch lifts the y axis above the horizon, roll turns about y (right
 * side down positive), heading is the compass heading of the y axis (from north,
 * clockwise positive), all wrapped to (-pi, pi].
 *
 * Fixed build: quaternion and unit-vector components are Q30 with magnitude at
 * most 1 (+ rounding), so products of two of them and sums of up to four such
 * products stay below 2^62 in int64 and below 2 (Q30's range) after the shift:
 * the helpers below use non-saturating arithmetic for them. Functions that take
 * vectors of unbounded magnitude say so.
 */
#ifndef IMU_MATH_H
#define IMU_MATH_H

#include "imu_arith.h"

/**
 * @brief Unit vector of v and its length.
 * @param v     vector in any Q format (all three components the same format), any int32.
 * @param unit  output, Q30; untouched when v is zero. NULL: the length alone (the same
 *              value, without the reciprocal and the three products).
 * @param norm  output (may be NULL), |v| in the format of v, saturated to int32.
 * @return 1 on success, 0 when v is the zero vector.
 */
int imu_vec3_normalize(const imu_real_t v[3], imu_q30_t unit[3], imu_real_t *norm);

/** @brief sqrt(a^2 + b^2) of two values of the same Q format, floored; saturated to int32. */
imu_real_t imu_hypot(imu_real_t a, imu_real_t b);

/** @brief |v| in v's Q format, rounded to nearest (a floor would bias every magnitude low
 *  against the float build's); saturated to int32. */
imu_real_t imu_vec3_norm(const imu_real_t v[3]);

/** @brief out = a x b for Q30 vectors of magnitude <= 1 (result Q30). */
void imu_vec3_cross(const imu_q30_t a[3], const imu_q30_t b[3], imu_q30_t out[3]);

/**
 * @brief v <- v - theta x v: a vector fixed in the earth frame, seen from the sensor frame
 *        after it turned by the small rotation theta (first order).
 * @param v      any Q format, |v| (1 + |theta|) below 2^31 in it (the result fits int32)
 * @param theta  rotation vector, rad, Q30, |theta| at most 1
 */
void imu_vec3_turn_back(imu_real_t v[3], const imu_q30_t theta[3]);

/** @brief Normalise a quaternion in place (components Q30, magnitude near 1, at most 2). */
void imu_quat_normalize(imu_q30_t q[4]);

/** @brief out = a (x) b, Hamilton product of unit quaternions (Q30); out may alias neither. */
void imu_quat_mul(const imu_q30_t a[4], const imu_q30_t b[4], imu_q30_t out[4]);

/** @brief Row `row` (0: east, 1: north, 2: up) of the sensor-to-earth rotation matrix of q (Q30). */
void imu_quat_matrix_row(const imu_q30_t q[4], int row, imu_q30_t out[3]);

/** @brief Column 1 of the rotation matrix of q: the sensor's y axis in the earth frame, Q30. */
void imu_quat_y_axis(const imu_q30_t q[4], imu_q30_t out[3]);

/** The sensor-to-earth rotation matrix of a quaternion, by rows (imu_quat_matrix_row), Q30. */
typedef struct {
    imu_q30_t row[3][3]; /**< row[0]: east, row[1]: north, row[2]: up, in the sensor frame */
} imu_rotation_t;

/** @brief The rotation matrix of q: its three rows (imu_quat_matrix_row). */
void imu_quat_rotation(const imu_q30_t q[4], imu_rotation_t *r);

/** @brief out = R v: the sensor-frame v in the earth frame (v and out in any one Q format). */
void imu_rotation_apply(const imu_rotation_t *r, const imu_real_t v[3], imu_real_t out[3]);

/**
 * @brief q <- normalize(q (x) exp(theta / 2)): advance the attitude by a body-frame
 *        rotation vector.
 * @param theta rotation vector in rad, Q30. A step longer than 1 rad (a sample
 *        rate far too low for the motion) is limited to 1 rad, direction kept.
 *
 * Fixed build: cos and sin(x)/x of the half angle x = |theta|/2 by their Taylor
 * series to x^4 (truncation 2.2e-5 at the 1 rad limit, 7e-8 at 0.5 rad, below
 * 1e-11 at the 0.035 rad steps of 200 deg/s at 100 Hz). Float build: exact cos and sin.
 */
void imu_quat_integrate(imu_q30_t q[4], const imu_q30_t theta[3]);

/**
 * @brief q = exp(theta / 2): imu_quat_integrate of the identity quaternion, the same
 *        integers without the product by the identity (some 70 Cortex-M4 instructions fewer).
 */
void imu_quat_from_rotation(imu_q30_t q[4], const imu_q30_t theta[3]);

/**
 * @brief Turn q (Q30) by a small body-frame rotation vector theta (Q30 rad), as a
 *        correction does: q <- q (x) (1 - |theta|^2/8, theta/2) below |theta| = 1/64 rad,
 *        imu_quat_integrate above.
 *
 * The series step is the exponential to second order: its rotation is long by
 * |theta|^3/24 (below 1.6e-7 rad at the bound) and its norm by |theta|^4/128 (below
 * 2^-31, under the Q30 rounding). It is rounded once (ties to even), not normalised (the
 * next imu_quat_integrate normalises exactly): some 140 Cortex-M4 instructions where
 * imu_quat_integrate takes 345.
 */
void imu_quat_turn(imu_q30_t q[4], const imu_q30_t theta[3]);

/** @brief atan2(y, x) in (-pi, pi] (Q29 rad); x and y in the same Q format. atan2(0, 0) = 0. */
imu_angle_t imu_atan2(imu_real_t y, imu_real_t x);

/** @brief sin and cos (Q30) of an angle in rad (Q29, any value of the type). */
void imu_sincos(imu_angle_t angle, imu_q30_t *s, imu_q30_t *c);

/** @brief Wrap an angle (Q29 rad, any value of the type) to (-pi, pi]. */
imu_angle_t imu_wrap_angle(imu_angle_t a);

/** @brief wrap(a + b) for any two angles (Q29 rad); the sum is formed without overflow. */
imu_angle_t imu_angle_add(imu_angle_t a, imu_angle_t b);

/** @brief wrap(a - b) for any two angles (Q29 rad); the difference is formed without overflow. */
imu_angle_t imu_angle_diff(imu_angle_t a, imu_angle_t b);

/** @brief Euler angles [roll, pitch, heading] (Q29 rad) of a unit quaternion. */
void imu_quat_to_euler(const imu_q30_t q[4], imu_angle_t euler[3]);

/** What imu_quat_to_euler_axes reads the Euler angles from (Q30): with them, the sines and
 *  cosines of roll r and pitch p of a unit quaternion without a sine or cosine of its own. */
typedef struct {
    imu_q30_t up[3];   /**< row 2 of R, the earth's up in the sensor frame: (-sin r cos p, sin p, cos r cos p) */
    imu_q30_t y[3];    /**< column 1 of R, the sensor's y axis in the earth frame: y[2] = sin p */
    imu_q30_t cos_pitch; /**< cos p = |(y[0], y[1])|, at least 0 */
} imu_euler_axes_t;

/** @brief imu_quat_to_euler, the same angles, and the axes they were read from. */
void imu_quat_to_euler_axes(const imu_q30_t q[4], imu_angle_t euler[3], imu_euler_axes_t *axes);

/** @brief Unit quaternion of Euler angles [roll, pitch, heading] (Q29 rad). */
void imu_euler_to_quat(const imu_angle_t euler[3], imu_q30_t q[4]);

/**
 * @brief Roll and pitch (Q29 rad) from a specific-force vector (any Q format),
 *        as a level accelerometer reads +g on z. Leaves the angles untouched and
 *        returns 0 when the vector is zero.
 */
int imu_tilt_from_acc(const imu_real_t acc[3], imu_angle_t *roll, imu_angle_t *pitch);

/**
 * @brief Compass heading (Q29 rad, clockwise from north) of the magnetic field
 *        `mag` (any Q format) after removing roll and pitch (tilt compensation).
 */
imu_angle_t imu_heading_from_mag(const imu_real_t mag[3], imu_angle_t roll, imu_angle_t pitch);

/** @brief imu_heading_from_mag for a tilt given as the sines and cosines (Q30) of roll and pitch. */
imu_angle_t imu_heading_from_mag_tilt(const imu_real_t mag[3], imu_q30_t sr, imu_q30_t cr, imu_q30_t sp, imu_q30_t cp);

/**
 * @brief Weight of a measurement whose input departs from its model:
 *        w = 1 / (1 + (deviation / tolerance)^2)^2 in Q30, 0 beyond 16 tolerances.
 *
 * Flat near zero (small deviations keep the full weight), continuous (a fixed and a
 * float build never take different branches), deviation and tolerance in Q24 with
 * 0 < tolerance < 2.
 */
imu_q30_t imu_deviation_weight(imu_real_t deviation, imu_real_t tolerance, uint32_t *sat);

/**
 * @brief Steady noise variance of the exponential low-pass y <- y + alpha (x - y) over one
 *        white input's: alpha / (2 - alpha), Q30 (alpha Q30 in (0, 1]).
 */
imu_q30_t imu_lowpass_noise_share(imu_q30_t alpha, uint32_t *sat);

/**
 * @brief Dip of a unit field in the earth frame (ENU; positive below the horizon) and its
 *        horizontal length. @param earth unit field, Q30 @param horizontal out, Q30
 * @return rad, Q29
 */
imu_angle_t imu_field_dip(const imu_q30_t earth[3], imu_q30_t *horizontal);

/**
 * @brief How far a magnetic field is from a reference field, as a weight in [0, 1] (Q30):
 *        the product of imu_deviation_weight of the norm's relative deviation and of the
 *        dip's (a magnet, steel or a motor nearby changes either). The one rule of the
 *        attitude ESKF and the nav filter.
 * @param norm, ref_norm the field's and the reference's strength, any one unit, Q16 (ref_norm > 0)
 * @param dip, ref_dip   their dips, rad, Q29 (imu_field_dip)
 * @param norm_tolerance relative, Q24 (below 2); @param dip_tolerance rad, Q24 (below 2)
 * @param w_norm         out: the norm's weight alone, Q30
 */
imu_q30_t imu_field_weight(imu_real_t norm, imu_real_t ref_norm, imu_angle_t dip, imu_angle_t ref_dip,
                           imu_real_t norm_tolerance, imu_real_t dip_tolerance, imu_q30_t *w_norm, uint32_t *sat);

/** The magnetic-disturbance rule's times, s, Q16: a new field replaces the reference once it
 *  has held for longer than the reference was trusted and for at least IMU_FIELD_NEW_TIME;
 *  trust counts up to IMU_FIELD_TRUST_LIMIT (VQF's longest rejection of a disturbance). */
#define IMU_FIELD_NEW_TIME IMU_QCONST(20.0, 16)
#define IMU_FIELD_TRUST_LIMIT IMU_QCONST(60.0, 16)

/**
 * @brief The one rule of the attitude ESKF and the nav filter for replacing a magnetic
 *        reference: a disturbance that stays (a magnet beside the board for half a minute)
 *        does not outweigh the field that held for minutes before it, and a field taken by
 *        mistake is given up as quickly as it was taken. Counts are steps of the caller's
 *        (the ESKF counts only the steps in which the board turns: only then can a field
 *        fixed to the earth be told from one fixed to the board).
 */
typedef struct {
    int32_t trusted; /**< steps the reference held, up to the caller's limit */
    int32_t held;    /**< steps the candidate (a new field) has held */
} imu_field_trust_t;

/** @brief A new reference: no trust yet, no candidate. */
void imu_field_trust_reset(imu_field_trust_t *t);

/** @brief The reference held for `steps` (0 or 1) more steps: its trust grows (up to `limit`)
 *         and a candidate is given up. */
void imu_field_trust_confirm(imu_field_trust_t *t, int32_t steps, int32_t limit);

/** @brief The candidate is dropped (a different one, or the reference back). */
void imu_field_trust_drop(imu_field_trust_t *t);

/**
 * @brief The candidate held for `steps` (0 or 1) more steps. Returns 1 when it replaces the
 *        reference: it has held for at least `minimum` and for longer than the reference
 *        was trusted; its count then becomes the new reference's trust.
 */
int imu_field_trust_hold(imu_field_trust_t *t, int32_t steps, int32_t minimum);

#endif /* IMU_MATH_H */
