/**
 * @file imu_navkf.c
 * @brief Loosely coupled GNSS/INS navigation filter (see imu_navkf.h).
 */
#include "imu_navkf.h"

#include "imu_math.h"

enum { POS = 0, VEL = 3, ATT = 6, GYRO_BIAS = 9, ACC_BIAS = 12, BARO_BIAS = 15 };

static const imu_navkf_tuning_t DEFAULT_TUNING = IMU_NAVKF_DEFAULT_TUNING;

/** The barometer's bias, a random walk of 2.5 m/sqrt(h) (the weather: 30 Pa/sqrt(h)), in units of 1024 m */
#define NOISE_BARO_BIAS IMU_QCONST(1.7e-3 / 1048576.0, 54)

/* Initial standard deviations in the states' units, Q30: velocity 1 m/s, roll and pitch
 * 2 deg, heading 10 deg (from a magnetometer), gyro bias 1.5 deg/s, accelerometer bias
 * 0.5 m/s^2. Position: the first fix's accuracy. */
#define START_VEL IMU_QCONST(1.0 / 64.0, 30)
#define START_TILT IMU_QCONST(0.034906585, 30)
#define START_HEADING IMU_QCONST(0.17453293, 30)
#define START_GYRO_BIAS IMU_QCONST(0.026179939, 30)
#define START_ACC_BIAS IMU_QCONST(0.5, 30)
#define START_BARO_BIAS IMU_QCONST(20.0 / 1024.0, 30) /* 20 m: the first sample's height is the estimate's */
/* Before the first fix (a start without one) the position is nowhere: its standard deviation
 * 1024 m (nothing measures it; the first fix replaces it), normal gravity and the radii
 * those of latitude 45 deg (within 0.03 m/s^2 of anywhere's). */
#define UNANCHORED_POS IMU_QCONST(1.0, 30)
#define UNANCHORED_LAT IMU_QCONST(0.78539816339744831, 29)

/* The barometer: a height every BARO_INTERVAL at most (s, Q16; a sample's noise is 0.1 m,
 * what limits it is slower), each of standard deviation BARO_SIGMA (0.3 m, in units of
 * 1024 m, Q30). Pressures outside BARO_MIN_PA .. BARO_MAX_PA are not air's. The height
 * from a pressure p against a reference (p0, h0): h0 - H ln(p / p0), the isothermal
 * atmosphere's with the scale height H = R T / (M g) at the ISA temperature of h0
 * (288.15 K - 6.5 K/km), the logarithm's series in u = (p - p0) / p0 to u^4 (2 cm at
 * |u| = 0.1); past |u| = BARO_REFERENCE_SPAN the reference moves to the sample. */
#define BARO_INTERVAL IMU_QCONST(1.0, 16)
#define BARO_SIGMA IMU_QCONST(0.3 / 1024.0, 30)
#define BARO_MIN_PA 10000
#define BARO_MAX_PA 120000
#define BARO_REFERENCE_SPAN IMU_QCONST(0.05, 30)
#define SCALE_HEIGHT_SEA_MM IMU_QCONST(8434675.0, 0)     /* 29.27175 m/K * 288.15 K, mm */
#define SCALE_HEIGHT_PER_MM IMU_QCONST(0.19026636, 30)   /* 29.27175 m/K * 6.5 K/km: mm of H per mm of height */

/* Rest: the bias-corrected rate and the specific force's distance from gravity within the
 * tuning's bounds for a covariance interval (50 ms: a foot's stance is some 0.5 s); with
 * GNSS, only while the last fix's speed is below REST_SPEED (m/s, Q20): a car cruising
 * straight is as still as a parked one. */
#define REST_SPEED IMU_QCONST(0.3, 20)
/** Below SLOW_SPEED (m/s, Q20) the board walks: through an outage, rest is the sensors' (a
 *  car cruising through a tunnel is as still as a foot in its stance, but not as slow). */
#define SLOW_SPEED IMU_QCONST(2.0, 20)
/* ... and, with GNSS, weighted by how steady the specific force is: its low-passes over
 * 0.1 s and 1 s (weights per sample dt / tau) apart by 0.02 m/s^2 (Q24) on an axis weigh a
 * quarter (imu_deviation_weight: continuous, so that the fixed and float builds never take
 * different branches). A car setting off gently keeps its rate and the norm of its force;
 * the force's slow rise is what shows. */
#define TREND_FAST_TAU IMU_QCONST(0.1, 16)
#define TREND_SLOW_TAU IMU_QCONST(1.0, 16)
#define TREND_TOLERANCE IMU_QCONST(0.02, 24)
/** Zero velocity's standard deviation: 0.02 m/s in units of 64 m/s, Q30 (zero rate's: the
 *  gyroscope's noise, the tuning's over a sample). */
#define ZERO_VELOCITY_SIGMA IMU_QCONST(0.02 / 64.0, 30)
/** The magnetometer's heading: the standard deviation of the unit field's east
 *  component (about the sine of the heading error times the field's horizontal share),
 *  Q30: 0.02, a microtesla of noise and disturbance in a 50 uT field. */
#define FIELD_EAST_SIGMA IMU_QCONST(0.02, 30)
/** ... weighed by how far the field's strength and dip are from the start's (imu_field_weight, the
 *  attitude ESKF's rule): 10 % of the strength or 0.05 rad of dip weighs a quarter (Q24); a field
 *  whose weight is below a half (6 % or 0.03 rad off: iron, a magnet, a motor nearby) is left out,
 *  however long it stays: its error does not average out as noise does. */
#define FIELD_TOLERANCE IMU_QCONST(0.1, 24)
#define DIP_TOLERANCE IMU_QCONST(0.05, 24)
#define FIELD_DISTURBED IMU_QCONST(0.5, 30)
/** ... and a heading that departs from the estimate's by more than 3 standard deviations of
 *  their difference (a chi-square bound, Q16) is left out too: a field a few microtesla
 *  off in strength and dip, which the weight lets through, turns the heading by degrees. */
#define FIELD_GATE IMU_QCONST(9.0, 16)
/** The field's turn against the gyroscope (field_still): the sine of 2 deg (Q29) beyond its
 *  low-pass over 2 s (the weight per covariance interval, 50 ms / 2 s, Q30) turns it out
 *  (some five times the data sheet's noise in a horizontal field of 20 uT); within the sine
 *  of 1 deg of where it was it is back; otherwise the turned field becomes the field by the
 *  rule the attitude ESKF shares (imu_field_trust_t): once it has been held out for longer
 *  than the field before it held, and for at least FIELD_NEW intervals (IMU_FIELD_NEW_TIME,
 *  20 s); the trust counts up to FIELD_TRUST_LIMIT intervals (IMU_FIELD_TRUST_LIMIT, 60 s:
 *  the longest a field is held out, as before the rule was shared). Below
 *  FIELD_MIN_HORIZONTAL (Q30) of horizontal share (near a magnetic pole) the field shows no
 *  heading. */
#define FIELD_TURN IMU_QCONST(0.0348995, 29)
#define FIELD_TURN_BACK IMU_QCONST(0.0174524, 29)
#define FIELD_TURN_WEIGHT IMU_QCONST(0.025, 30)
#define FIELD_NEW 400
#define FIELD_TRUST_LIMIT 1200
#define FIELD_MIN_HORIZONTAL IMU_QCONST(0.1, 30)
/** The dip's reference is the mean of the dips seen in the estimate's frame while the field's
 *  strength is the start's (its weight at least FIELD_DISTURBED): over all of them for the
 *  first DIP_MEMORY covariance intervals, then a running mean over about as many (51 s). One
 *  sample's attitude is no reference: a start on a running engine tilts it by degrees, and
 *  its dip with it, which would leave the field out for good. */
#define DIP_MEMORY 1024
/** Without GNSS, the tilt from the accelerometer: the standard deviation of the force
 *  direction's horizontal components (Q30: 0.05, some 3 deg: the board's own accelerations
 *  between the samples the weight lets through), the weight a quarter 0.2 m/s^2 (Q24) from
 *  gravity's strength. */
#define GRAVITY_SIGMA IMU_QCONST(0.05, 30)
#define GRAVITY_TOLERANCE IMU_QCONST(0.2, 24)

/* Two consecutive fixes agree with each other when the one's position moved by the
 * receiver's mean velocity between them (without velocity: the estimate's displacement, the
 * corrections taken off) lands within GATE_SIGMAS standard deviations of the other (their
 * difference's, Q16). RAYLEIGH_MEAN (Q16): the mean length of a horizontal difference of unit
 * variance per axis, sqrt(pi / 2): the running mean of the fixes' normalised disagreement is
 * that when they are as accurate as the receiver says; beyond, their accuracies are inflated
 * by its ratio to it (each disagreement counted up to SPREAD_CAP, Q16, so that an outlier
 * weighs little; the mean over some SPREAD_FIXES fixes). */
#define GATE_SIGMAS IMU_QCONST(4.0, 16)
#define RAYLEIGH_MEAN IMU_QCONST(1.2533141, 16)
#define SPREAD_CAP IMU_QCONST(5.0, 16)
#define SPREAD_WEIGHT IMU_QCONST(1.0 / 16.0, 30)
/** The most a fix scales the covariance by: each standard deviation doubled up to MAX_FADE
 *  times (until the fix passes the gate), the attitude's ATTITUDE_FADE times at most (an
 *  estimate in doubt is most often a bias that stepped: the attitude's error is that bias
 *  integrated since, a few degrees, and the magnetometer and gravity keep observing it;
 *  freed further, the attitude would absorb what a fix's velocity says about the tilt as a
 *  heading error while the board accelerates). */
#define MAX_FADE 5
#define ATTITUDE_FADE 2

/** Unit conversions into the states' units (Q30): mm to 1024 m (Q50 factor, >> 20),
 *  mm/s to 64 m/s (Q46, >> 16), m/s Q20 to 64 m/s (Q36, >> 26). */
#define MM_TO_POS IMU_QCONST(1.0 / 1024000.0, 50)
#define MM_TO_POS_AXIS IMU_QCONST(0.70710678118654752 / 1024000.0, 50) /* per horizontal axis */
#define MM_S_TO_VEL IMU_QCONST(1.0 / 64000.0, 46)
#define Q20_TO_VEL IMU_QCONST(1.0 / 64.0, 36)

/** Seconds (Q16): the covariance's interval; fixes further apart than GAP_TIME are not
 *  compared; the longest count kept (how long without GNSS before rest alone makes zero
 *  velocity). */
#define COV_INTERVAL IMU_QCONST(0.05, 16)
#define GAP_TIME IMU_QCONST(2.5, 16)
#define LONGEST_COUNT IMU_QCONST(60.0, 16)

/** The antenna's lever arm: each axis within +-10 m (mm). */
#define MAX_LEVER_ARM_MM IMU_QCONST(10000.0, 0)

static const int POSITION_ROWS[3] = {POS, POS + 1, POS + 2};
static const int VELOCITY_ROWS[3] = {VEL, VEL + 1, VEL + 2};
static const int ATTITUDE_ROWS[3] = {ATT, ATT + 1, ATT + 2};
/** The gain map of a receiver's position: everything but the attitude and the gyro bias (blocks of three states). */
static const imu_navcov_map_t POSITION_ONLY = {
    {IMU_COV_BLOCK_ALL, IMU_COV_BLOCK_ALL, IMU_COV_BLOCK_NONE, IMU_COV_BLOCK_NONE, IMU_COV_BLOCK_ALL, IMU_COV_BLOCK_ALL},
    {0, 0, 0}};

static void matrix(const imu_q30_t q[4], imu_q30_t r[3][3])
{
    int k;
    for (k = 0; k < 3; ++k) {
        imu_quat_matrix_row(q, k, r[k]);
    }
}

/** rows[i][first + j] = -(a x column j of r)_i: the columns of -[a x] R. */
static void minus_cross_columns(const imu_q30_t a[3], imu_q30_t r[3][3], imu_q30_t rows[3][IMU_NAVCOV_MAX],
                                int first)
{
    int i, j;
    for (j = 0; j < 3; ++j) {
        const imu_q30_t column[3] = {r[0][j], r[1][j], r[2][j]};
        imu_q30_t c[3];
        imu_vec3_cross(a, column, c);
        for (i = 0; i < 3; ++i) {
            rows[i][first + j] = -c[i]; /* |c| <= 1 */
        }
    }
}

static void clear_rows(imu_q30_t rows[3][IMU_NAVCOV_MAX])
{
    int i, j;
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < IMU_NAVCOV_MAX; ++j) {
            rows[i][j] = 0;
        }
    }
}

/**
 * The covariance over the interval of `steps` samples (T s): P <- Phi P Phi^T + Q with, in
 * the states' units, R0 and R1 the attitude at the interval's start and end, Rm their
 * mean, dv the specific force integrated over it (ENU), A = R1^T R0:
 *   position: p + T v - [(dv T / 2) x] R0 dtheta - Rm (T^2 / 2) ba
 *   velocity: v - [dv x] R0 dtheta - Rm T ba
 *   attitude: A dtheta - T (I + A) / 2 bg
 * (the earth-frame attitude error R dtheta stays put while the board turns, so the
 * specific force's effect integrates to [dv x]), applied as three factors.
 */
static void covariance_step(imu_navkf_t *f)
{
    uint32_t *sat = &f->nav.saturations;
    imu_q30_t r0[3][3], r1[3][3], rm[3][3], a[3][3];
    imu_q30_t rows[3][IMU_NAVCOV_MAX];
    imu_wide_t qvar[IMU_NAVCOV_MAX];
    imu_q30_t dvu[3], pu[3];
    const imu_q30_t t = f->nav.dt * f->steps; /* s, Q30: at most 0.1 s * cov_steps (below 0.25 s) */
    const imu_q30_t t16 = IMU_MUL(t, IMU_QCONST(1.0 / 16.0, 30), 30); /* T 64 m/s / 1024 m */
    const imu_q30_t t32 = IMU_MUL(t, IMU_QCONST(1.0 / 32.0, 30), 30);
    const imu_q30_t t64 = IMU_MUL(t, IMU_QCONST(1.0 / 64.0, 30), 30);
    const imu_q30_t t2 = IMU_MUL(t64, t32, 30);                        /* T^2 / 2 / 1024 */
    int i, j, k;
    matrix(f->q_start, r0);
    matrix(f->nav.q, r1);
    for (k = 0; k < 3; ++k) {
        dvu[k] = IMU_WIDE_SAT(IMU_WSHR(f->dv[k], 22), sat); /* Q52 -> Q30, units of 64 m/s */
        if (dvu[k] > IMU_ONE_Q30 || dvu[k] < -IMU_ONE_Q30) {
            /* 64 m/s in 50 ms (1 300 m/s^2) is no accelerometer's: held at one unit, counted,
             * so that the cross products below stay within Q30 */
            dvu[k] = dvu[k] > 0 ? IMU_ONE_Q30 : -IMU_ONE_Q30;
            ++*sat;
        }
        pu[k] = IMU_MUL(dvu[k], t32, 30); /* dv T / 2 in units of 1024 m */
    }
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < 3; ++j) {
            rm[i][j] = IMU_ADD(IMU_HALF(r0[i][j]), IMU_HALF(r1[i][j]));
            a[i][j] = IMU_ADD(IMU_ADD(IMU_MUL(r1[0][i], r0[0][j], 30), IMU_MUL(r1[1][i], r0[1][j], 30)),
                              IMU_MUL(r1[2][i], r0[2][j], 30));
        }
    }
    for (i = 0; i < IMU_NAVCOV_MAX; ++i) {
        qvar[i] = 0;
    }

    clear_rows(rows);
    minus_cross_columns(pu, r0, rows, ATT);
    for (i = 0; i < 3; ++i) {
        rows[i][POS + i] = IMU_ONE_Q30;
        rows[i][VEL + i] = t16;
        for (j = 0; j < 3; ++j) {
            rows[i][ACC_BIAS + j] = -IMU_MUL(rm[i][j], t2, 30);
        }
    }
    imu_navcov_predict(&f->cov, rows, POSITION_ROWS, 3, qvar, NULL, 60, sat);

    clear_rows(rows);
    minus_cross_columns(dvu, r0, rows, ATT);
    for (i = 0; i < 3; ++i) {
        rows[i][VEL + i] = IMU_ONE_Q30;
        for (j = 0; j < 3; ++j) {
            rows[i][ACC_BIAS + j] = -IMU_MUL(rm[i][j], t64, 30);
        }
    }
    imu_navcov_predict(&f->cov, rows, VELOCITY_ROWS, 3, qvar, NULL, 60, sat);

    clear_rows(rows);
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < 3; ++j) {
            rows[i][ATT + j] = a[i][j];
            /* -T (delta_ij + a_ij) / 2 */
            rows[i][GYRO_BIAS + j] = -IMU_ADD(i == j ? IMU_HALF(t) : 0, IMU_MUL(IMU_HALF(t), a[i][j], 30));
        }
        /* Q54 per second * s Q30 >> 24 -> Q60 */
        qvar[VEL + i] = IMU_WSHR(IMU_WMUL(f->noise_vel, t), 24) + f->clipped_var;
        qvar[ATT + i] = IMU_WSHR(IMU_WMUL(f->noise_att, t), 24);
        qvar[GYRO_BIAS + i] = IMU_WSHR(IMU_WMUL(f->noise_gyro_bias, t), 24);
        qvar[ACC_BIAS + i] = IMU_WSHR(IMU_WMUL(f->noise_acc_bias, t), 24);
    }
    qvar[BARO_BIAS] = IMU_WSHR(IMU_WMUL(NOISE_BARO_BIAS, t), 24);
    imu_navcov_predict(&f->cov, rows, ATTITUDE_ROWS, 3, qvar, NULL, 60, sat);
    for (i = 0; i < 3; ++i) {
        imu_navcov_cap_unit_variance(&f->cov, ATT + i); /* an attitude error beyond a radian means nothing */
    }
}

/** Start a covariance interval at the current attitude. */
static void restart_interval(imu_navkf_t *f)
{
    int k;
    for (k = 0; k < 4; ++k) {
        f->q_start[k] = f->nav.q[k];
    }
    for (k = 0; k < 3; ++k) {
        f->dv[k] = 0;
    }
    f->clipped_var = 0;
    f->steps = 0;
}

/** Bring the covariance up to the current sample. */
static void flush(imu_navkf_t *f)
{
    if (f->steps > 0) {
        covariance_step(f);
    }
    restart_interval(f);
}

static void clear(imu_q30_t dx[IMU_NAVKF_STATES])
{
    int k;
    for (k = 0; k < IMU_NAVKF_STATES; ++k) {
        dx[k] = 0;
    }
}

/** One scalar measurement with row h (Q30, the states' units): innovation z (Q30; what
 *  earlier parts of the same measurement corrected, h . dx, is taken off here), variance
 *  r / w (r: Q60, unit^2; w: a weight in [0, 1], Q30). */
static void measure_row(imu_navkf_t *f, const imu_q30_t h[IMU_NAVKF_STATES], imu_q30_t z, imu_wide_t r, imu_q30_t w,
                        const imu_navcov_map_t *gain_map, imu_q30_t dx[IMU_NAVKF_STATES])
{
    uint32_t *sat = &f->nav.saturations;
    imu_wide_t corrected = 0; /* h . dx, Q60 */
    int j;
    for (j = 0; j < IMU_NAVKF_STATES; ++j) {
        corrected += IMU_WMUL(h[j], dx[j]);
    }
    (void)imu_navcov_update(&f->cov, h, r, 60, IMU_SUB_SAT(z, IMU_WIDE_SAT(IMU_WSHR(corrected, 30), sat), sat), w,
                            gain_map, dx, sat);
}

/** The same for state i alone. */
static void measure(imu_navkf_t *f, int i, imu_q30_t z, imu_wide_t r, imu_q30_t w, imu_q30_t dx[IMU_NAVKF_STATES])
{
    imu_q30_t h[IMU_NAVKF_STATES];
    clear(h);
    h[i] = IMU_ONE_Q30;
    measure_row(f, h, z, r, w, NULL, dx);
}

/** A sensor-frame unit vector (Q30) in the earth frame (ENU, Q30) of the attitude matrix r. */
static void to_earth(imu_q30_t r[3][3], const imu_q30_t unit[3], imu_q30_t earth[3])
{
    int k;
    for (k = 0; k < 3; ++k) {
        earth[k] = IMU_ADD(IMU_ADD(IMU_MUL(r[k][0], unit[0], 30), IMU_MUL(r[k][1], unit[1], 30)),
                           IMU_MUL(r[k][2], unit[2], 30));
    }
}

/** The corrections dx (the states' units, Q30) applied to the strapdown state. */
static void apply(imu_navkf_t *f, const imu_q30_t dx[IMU_NAVKF_STATES])
{
    uint32_t *sat = &f->nav.saturations;
    imu_nav_t *n = &f->nav;
    imu_wide_t step[3];
    imu_q30_t theta[3];
    int k;
    for (k = 0; k < 3; ++k) {
        step[k] = IMU_WSHR(IMU_WMUL(dx[POS + k], 1024000), 15); /* units Q30 * 1024000 -> mm Q30 >> 15 -> Q15 */
        /* Each correction's rounding is carried to the next (the biases are unobservable at
         * times: rounded alone, their corrections would random-walk them, and the heading
         * with them, away from the float build's). Units of 64 m/s, Q30 -> m/s Q20: * 64 >> 10,
         * the same integer as Q30 >> 4 */
        n->vel[k] = IMU_ADD_SAT(n->vel[k], IMU_WSHR_FEEDBACK_SAT(IMU_WMUL(dx[VEL + k], IMU_QCONST(64.0, 24)), 34,
                                                                 &f->carry[VEL + k], sat), sat);
        theta[k] = dx[ATT + k];
        n->gyro_bias[k] = IMU_ADD_SAT(n->gyro_bias[k], IMU_WSHR_FEEDBACK_SAT(dx[GYRO_BIAS + k], 6,
                                                                             &f->carry[GYRO_BIAS + k], sat), sat);
        n->acc_bias[k] = IMU_ADD_SAT(n->acc_bias[k], IMU_WSHR_FEEDBACK_SAT(dx[ACC_BIAS + k], 14,
                                                                           &f->carry[ACC_BIAS + k], sat), sat);
    }
    /* units of 1024 m, Q30 -> mm (* 1024000 >> 30), the rounding carried */
    f->baro_bias = IMU_ADD_SAT(f->baro_bias, IMU_WSHR_FEEDBACK_SAT(IMU_WMUL(dx[BARO_BIAS], 1024000), 30,
                                                                   &f->carry[BARO_BIAS], sat), sat);
    for (k = 0; k < 3; ++k) {
        f->moved[k] = IMU_ADD_SAT(f->moved[k], IMU_WIDE_SAT(IMU_WSHR(step[k], 15), sat), sat); /* mm */
    }
    if (f->field_turned >= 0) {
        /* the correction turns the field seen in the estimate's frame, e -> e + phi x e (phi =
         * R theta, in ENU): its east share by phi_n up - phi_u north (per horizontal), which
         * the field's turn against the gyroscope is not (field_still) */
        imu_q30_t r[3][3], north = 0, up = 0; /* phi's, Q30 */
        uint32_t ignored = 0; /* corrections of the attitude below a radian, but for input that makes no sense */
        matrix(n->q, r);
        for (k = 0; k < 3; ++k) {
            north = IMU_ADD_SAT(north, IMU_MUL(r[1][k], theta[k], 30), &ignored);
            up = IMU_ADD_SAT(up, IMU_MUL(r[2][k], theta[k], 30), &ignored);
        }
        f->field_after = IMU_ADD_SAT(f->field_after,
                                     IMU_SUB_SAT(IMU_MUL_SAT(north, f->field_up, 25, &ignored),
                                                 IMU_MUL_SAT(up, f->field_north, 30, &ignored), &ignored),
                                     &ignored);
    }
    imu_nav_move(n, step);
    imu_quat_integrate(n->q, theta);
    restart_interval(f);
}

/** Velocity (m/s, Q20) in units of 64 m/s, Q30. */
static imu_q30_t velocity_units(imu_real_t v, uint32_t *sat)
{
    return IMU_MUL_SAT(v, Q20_TO_VEL, 26, sat);
}

/** At rest: zero velocity, and zero rate (the gyroscope reads its bias: the sample's
 *  bias-corrected rate is the gyro bias error's innovation); weight w (Q30). */
static void at_rest(imu_navkf_t *f, imu_q30_t w)
{
    uint32_t *sat = &f->nav.saturations;
    imu_q30_t dx[IMU_NAVKF_STATES];
    int k;
    clear(dx);
    for (k = 0; k < 3; ++k) {
        measure(f, VEL + k, IMU_NEG_SAT(velocity_units(f->nav.vel[k], sat), sat),
                IMU_WMUL(ZERO_VELOCITY_SIGMA, ZERO_VELOCITY_SIGMA), w, dx);
    }
    for (k = 0; k < 3; ++k) {
        /* rad/s Q24 -> Q30 (|rate| below 2 rad/s at rest) */
        measure(f, GYRO_BIAS + k, IMU_SHL_SAT(f->rate[k], 6, sat), f->zero_rate_var, w, dx);
    }
    apply(f, dx);
    ++f->zero_velocity;
}

/** z^2 / (h P h^T + sigma^2) of a measurement on the attitude alone (h: its three
 *  coefficients, Q30; z, sigma Q30), Q16 (the gate's own saturations are not counted). */
static imu_real_t attitude_nis(const imu_navkf_t *f, const imu_q30_t h[3], imu_q30_t z, imu_q30_t sigma)
{
    uint32_t ignored = 0;
    imu_real_t s = IMU_MUL_SAT(sigma, sigma, 30, &ignored); /* Q30 */
    int i, j;
    for (i = 0; i < 3; ++i) {
        for (j = 0; j < 3; ++j) {
            const imu_real_t p = imu_navcov_element_q30(&f->cov, ATT + i, ATT + j, &ignored);
            s = IMU_ADD_SAT(s, IMU_MUL_SAT(h[i], IMU_MUL_SAT(h[j], p, 30, &ignored), 30, &ignored), &ignored);
        }
    }
    return s > 0 ? IMU_DIV_SAT(IMU_MUL_SAT(z, z, 30, &ignored), s, 16, &ignored) : 0;
}

/**
 * An update that the component of a sensor-frame unit vector u (Q30), turned into ENU, along
 * an ENU unit vector e is zero. With R = R^ (I + [dtheta x]), e . R u = r . u + r . (dtheta x u)
 * = r . u + dtheta . (u x r), r = R^T e (for e = an axis, that row of R^): h = u x r on the
 * attitude error, z = -r . u; variance
 * sigma^2 / w (sigma Q30, w Q30 in [0, 1]). Only the attitude moves (through P the rest too).
 * A gate (Q16, > 0) leaves out an innovation whose square beyond it (against h P h^T + sigma^2).
 */
static void zero_component(imu_navkf_t *f, const imu_q30_t u[3], const imu_q30_t r[3], imu_q30_t sigma, imu_q30_t w,
                           imu_real_t gate, imu_q30_t dx[IMU_NAVKF_STATES])
{
    uint32_t *sat = &f->nav.saturations;
    imu_q30_t h[IMU_NAVKF_STATES];
    imu_real_t z = 0; /* Q30 */
    int k;
    clear(h);
    imu_vec3_cross(u, r, &h[ATT]);
    for (k = 0; k < 3; ++k) {
        z = IMU_SUB_SAT(z, IMU_MUL(r[k], u[k], 30), sat);
    }
    if (gate > 0 && attitude_nis(f, &h[ATT], z, sigma) > gate) {
        return;
    }
    measure_row(f, h, z, IMU_WMUL(sigma, sigma), w, NULL, dx);
}

/** The field's east component over its horizontal one (the sine of its heading in the
 *  estimate's frame), Q29 (0 where the field is all but vertical). */
static imu_angle_t east_share(imu_q30_t east, imu_q30_t horizontal)
{
    uint32_t ignored = 0; /* |east| <= horizontal: within the range */
    return horizontal >= FIELD_MIN_HORIZONTAL ? IMU_DIV_SAT(east, horizontal, 29, &ignored) : 0;
}

/** Whether the field's heading stays where the gyroscope says it should: its turn against
 *  the estimate since the last interval's update (what the gyroscope did not see) summed,
 *  against that sum's low-pass over 2 s. A gyro bias turns it slowly (0.5 deg/s
 *  leaves it 1 deg behind); a field that turns (iron, a magnet; also one that keeps its
 *  strength and dip, which the weight cannot see) turns it at once: beyond FIELD_TURN the
 *  field is left out until it turns back to where it was, or until the shared rule takes
 *  it (FIELD_NEW's comment: then the field as it is now is the field). */
static int field_still(imu_navkf_t *f, const imu_q30_t earth[3], imu_q30_t horizontal)
{
    uint32_t ignored = 0; /* sines, within [-1, 1], and sums of them over a minute at most */
    const imu_angle_t share = east_share(earth[0], horizontal);
    imu_angle_t turn; /* since the last interval, Q29 */
    if (horizontal >= FIELD_MIN_HORIZONTAL) {
        /* how a correction of the attitude moves the share (apply): north / horizontal, Q29;
         * up / horizontal, Q24 (within +-10 at FIELD_MIN_HORIZONTAL) */
        f->field_north = IMU_DIV_SAT(earth[1], horizontal, 29, &ignored);
        f->field_up = IMU_DIV_SAT(earth[2], horizontal, 24, &ignored);
    }
    if (f->field_turned < 0) { /* the first heading: nothing to compare with yet */
        f->field_turned = 0;
        f->field_after = share;
        return 1;
    }
    turn = IMU_SUB_SAT(share, f->field_after, &ignored);
    f->field_after = share;
    if (f->field_turned == 0) {
        /* the turn summed minus its low-pass: (apart + turn) (1 - weight) */
        const imu_angle_t summed = IMU_ADD_SAT(f->field_apart, turn, &ignored);
        f->field_apart = IMU_SUB(summed, IMU_MUL(summed, FIELD_TURN_WEIGHT, 30));
        if (f->field_apart <= FIELD_TURN && f->field_apart >= -FIELD_TURN) {
            imu_field_trust_confirm(&f->field_trust, 1, FIELD_TRUST_LIMIT);
            return 1;
        }
        f->field_turned = 1;
        f->field_away = f->field_apart;
        return 0;
    }
    f->field_away = IMU_ADD_SAT(f->field_away, turn, &ignored);
    if (f->field_away <= FIELD_TURN_BACK && f->field_away >= -FIELD_TURN_BACK) {
        imu_field_trust_drop(&f->field_trust); /* the field before is back */
    } else if (!imu_field_trust_hold(&f->field_trust, 1, FIELD_NEW)) {
        return 0;
    }
    f->field_turned = 0;
    f->field_apart = 0;
    return 1;
}

/** The magnetometer's heading: the field has no east component (the magnetic north is the
 *  north here); weight w (Q30), times how far the field's strength and dip are from the
 *  references (a disturbed field, below FIELD_DISTURBED, is left out). */
static void field_heading(imu_navkf_t *f, const imu_real_t mag[3], imu_q30_t w)
{
    uint32_t *sat = &f->nav.saturations;
    imu_q30_t unit[3], earth[3], dx[IMU_NAVKF_STATES], w_field, w_norm, horizontal, r[3][3];
    imu_angle_t dip; /* rad, Q29 */
    imu_real_t norm;
    if (f->field_reference <= 0 || !imu_vec3_normalize(mag, unit, &norm)) {
        return;
    }
    matrix(f->nav.q, r);
    to_earth(r, unit, earth);
    dip = imu_field_dip(earth, &horizontal);
    w_field = imu_field_weight(norm, f->field_reference, dip, f->dip_reference, FIELD_TOLERANCE, DIP_TOLERANCE,
                               &w_norm, sat);
    if (w_norm >= FIELD_DISTURBED) {
        uint32_t ignored = 0;
        f->dips_seen += f->dips_seen < DIP_MEMORY;
        f->dip_reference = IMU_ADD(f->dip_reference, IMU_DIV_SAT(IMU_SUB(dip, f->dip_reference),
                                                                 IMU_FROM_INT_SAT(f->dips_seen, 0, &ignored), 0,
                                                                 &ignored));
    }
    if (!field_still(f, earth, horizontal) || w_field < FIELD_DISTURBED) {
        return;
    }
    clear(dx);
    zero_component(f, unit, r[0], FIELD_EAST_SIGMA, IMU_MUL(w, w_field, 30), FIELD_GATE, dx);
    apply(f, dx);
}

/** The tilt from the accelerometer (without GNSS: an inertial solution alone would let the
 *  tilt drift with the gyro bias): the bias-corrected specific force points up, its east and
 *  north components zero; weighted by how far its strength is from gravity's. */
static void gravity_tilt(imu_navkf_t *f, const imu_q16_t acc[3])
{
    uint32_t *sat = &f->nav.saturations;
    imu_q16_t force[3];
    imu_q30_t unit[3], dx[IMU_NAVKF_STATES], w, r[3][3];
    imu_real_t norm; /* m/s^2, Q16 */
    int k;
    for (k = 0; k < 3; ++k) {
        force[k] = IMU_SUB_SAT(acc[k], f->nav.acc_bias[k], sat);
    }
    if (!imu_vec3_normalize(force, unit, &norm)) {
        return;
    }
    /* Q16 -> Q24 (the difference from gravity, below 2^23 for a force below 2^29) */
    w = imu_deviation_weight(IMU_SHL_SAT(IMU_SUB_SAT(norm, IMU_SHR(f->nav.gravity, 8), sat), 8, sat),
                             GRAVITY_TOLERANCE, sat);
    if (w <= 0) {
        return;
    }
    clear(dx);
    matrix(f->nav.q, r);
    zero_component(f, unit, r[0], GRAVITY_SIGMA, w, 0, dx);
    zero_component(f, unit, r[1], GRAVITY_SIGMA, w, 0, dx);
    apply(f, dx);
}

/** Whether the sample looks like rest: the bias-corrected rate (f->rate) and specific force. */
static int still_sample(const imu_navkf_t *f, const imu_q16_t acc[3])
{
    const imu_nav_t *n = &f->nav;
    const imu_q16_t g = IMU_SHR(n->gravity, 8); /* Q24 -> Q16 */
    const imu_real_t rest_rate = f->tuning.rest_rate, rest_force = f->tuning.rest_force; /* Q24, Q16 */
    imu_wide_t w2 = 0, f2 = 0;                  /* Q48 (rad/s)^2, Q32 (m/s^2)^2 */
    int k;
    for (k = 0; k < 3; ++k) {
        const imu_wide_t a = (imu_wide_t)acc[k] - n->acc_bias[k]; /* Q16, within 2^32 */
        /* an axis beyond the bounds is not still (and the squares below then stay far from overflow) */
        if (f->rate[k] > rest_rate || f->rate[k] < -rest_rate || a > g + rest_force || a < -(g + rest_force)) {
            return 0;
        }
        w2 += IMU_WMUL(f->rate[k], f->rate[k]);
        f2 += a * a;
    }
    return w2 < IMU_WMUL(rest_rate, rest_rate) && f2 > IMU_WMUL(g - rest_force, g - rest_force) &&
           f2 < IMU_WMUL(g + rest_force, g + rest_force);
}

/** Samples in a time (s, Q16, at most a minute), at least one. */
static int32_t seconds_in_steps(imu_navkf_t *f, imu_real_t seconds)
{
    /* s Q16 * 2^30 / dt Q30 -> samples Q16 (below 2^31 for a minute at 1 kHz) -> Q0 */
    const int32_t steps = IMU_TO_INT(IMU_DIV_SAT(seconds, f->nav.dt, 30, &f->nav.saturations), 16);
    return steps < 1 ? 1 : steps;
}

/** The antenna's offset from the sensor in ENU, R l, mm (r: the attitude's matrix, Q30). */
static void antenna_offset(const imu_navkf_t *f, imu_q30_t r[3][3], imu_real_t out[3])
{
    int k;
    for (k = 0; k < 3; ++k) {
        /* Q30 * m Q20 >> 30 -> m Q20 (|l| <= 10 m), * 1000 -> mm */
        out[k] = IMU_MUL(IMU_ADD(IMU_ADD(IMU_MUL(r[k][0], f->lever_arm[0], 30), IMU_MUL(r[k][1], f->lever_arm[1], 30)),
                                 IMU_MUL(r[k][2], f->lever_arm[2], 30)),
                         IMU_QCONST(1000.0, 20), 40);
    }
}

/** r x l for a row r of R (Q30) and the lever arm l (m, Q20): m, Q20. */
static void cross_arm(const imu_q30_t r[3], const imu_real_t l[3], imu_real_t out[3])
{
    out[0] = IMU_SUB(IMU_MUL(r[1], l[2], 30), IMU_MUL(r[2], l[1], 30));
    out[1] = IMU_SUB(IMU_MUL(r[2], l[0], 30), IMU_MUL(r[0], l[2], 30));
    out[2] = IMU_SUB(IMU_MUL(r[0], l[1], 30), IMU_MUL(r[1], l[0], 30));
}

/** The antenna position's sensitivity to the attitude error, axis k (ENU): R (I + [dtheta x]) l
 *  = R l - R [l x] dtheta, so its row is -(R [l x])_k = -(r_k x l) (r_k: row k of R), in units
 *  of 1024 m per rad (Q30): m Q20 is the same integer; the float build divides by 1024. */
static void lever_arm_row(const imu_navkf_t *f, const imu_q30_t row[3], imu_q30_t out[3])
{
    imu_real_t c[3];
    int j;
    cross_arm(row, f->lever_arm, c);
    for (j = 0; j < 3; ++j) {
        out[j] = -IMU_MUL(c[j], IMU_QCONST(1.0 / 1024.0, 40), 30);
    }
}

/** The antenna's velocity beside the sensor's, R (w x l), w the bias-corrected rate: m/s, Q20
 *  (its sensitivity to the attitude and gyro bias errors is left out: below a cm/s). */
static void antenna_velocity(const imu_navkf_t *f, imu_q30_t r[3][3], imu_real_t out[3])
{
    imu_real_t turn[3]; /* w x l, m/s, Q20: rad/s Q24 * m Q20 >> 24 */
    const imu_real_t *l = f->lever_arm;
    const imu_rate_t *w = f->rate;
    int k;
    turn[0] = IMU_SUB(IMU_MUL(w[1], l[2], 24), IMU_MUL(w[2], l[1], 24));
    turn[1] = IMU_SUB(IMU_MUL(w[2], l[0], 24), IMU_MUL(w[0], l[2], 24));
    turn[2] = IMU_SUB(IMU_MUL(w[0], l[1], 24), IMU_MUL(w[1], l[0], 24));
    for (k = 0; k < 3; ++k) {
        out[k] = IMU_ADD(IMU_ADD(IMU_MUL(r[k][0], turn[0], 30), IMU_MUL(r[k][1], turn[1], 30)),
                         IMU_MUL(r[k][2], turn[2], 30));
    }
}

/** Whether a fix's accuracies are within 1 mm (mm/s) .. 2^30. */
static int accuracies_in_range(const imu_navkf_fix_t *fix)
{
    return fix->h_acc >= 1 && fix->h_acc <= (1 << 30) && fix->v_acc >= 1 && fix->v_acc <= (1 << 30) &&
           fix->s_acc >= 1 && fix->s_acc <= (1 << 30);
}

/** Whether the board stands, from a GNSS fix's speed: a fix without velocity (NMEA's GGA)
 *  does not say: no rest from GNSS then. */
static void note_speed(imu_navkf_t *f, const imu_navkf_fix_t *fix)
{
    imu_wide_t speed2 = 0; /* Q40 */
    int fast = 0;          /* an axis at REST_SPEED or beyond: not at rest (its square is not needed) */
    int k;
    for (k = 0; k < 3 && fix->has_vel; ++k) {
        if (fix->vel[k] >= REST_SPEED || fix->vel[k] <= -REST_SPEED) {
            fast = 1;
        } else {
            speed2 += IMU_WMUL(fix->vel[k], fix->vel[k]);
        }
    }
    f->fix_stood = fix->has_vel && !fast && speed2 < IMU_WMUL(REST_SPEED, REST_SPEED);
}

/** The position (and the velocity, when the fix has one) taken from `fix` at the origin it
 *  makes, their covariance the fix's (velocity: START_VEL) with nothing shared with the
 *  other states; the barometer starts again from there. 0 for a fix out of range. */
static int anchor(imu_navkf_t *f, const imu_navkf_fix_t *fix)
{
    uint32_t *sat = &f->nav.saturations;
    imu_nav_origin_t origin;
    imu_q30_t r[3][3];
    imu_real_t arm_enu[3];
    imu_wide_t step[3];
    const imu_q30_t sigma_h = IMU_MUL_SAT(fix->h_acc, MM_TO_POS_AXIS, 20, sat);
    const imu_q30_t sigma_v = IMU_MUL_SAT(fix->v_acc, MM_TO_POS, 20, sat);
    int k;
    origin.lat = fix->lat;
    origin.lon = fix->lon;
    origin.height = fix->height;
    for (k = 0; k < 3 && fix->has_vel; ++k) {
        if (!(fix->vel[k] <= IMU_QCONST(IMU_NAV_MAX_SPEED, 20) && fix->vel[k] >= -IMU_QCONST(IMU_NAV_MAX_SPEED, 20))) {
            return 0;
        }
    }
    if (!accuracies_in_range(fix) || imu_nav_anchor(&f->nav, &origin) != IMU_OK) {
        return 0;
    }
    flush(f);
    /* the fix is the antenna's: the sensor is R l below it */
    matrix(f->nav.q, r);
    antenna_offset(f, r, arm_enu);
    for (k = 0; k < 3; ++k) {
        step[k] = IMU_WMUL(IMU_NEG_SAT(arm_enu[k], sat), IMU_QCONST(1.0, 15)); /* mm -> Q15 */
    }
    imu_nav_move(&f->nav, step);
    for (k = 0; k < 3; ++k) {
        const imu_q30_t sigma = k < 2 ? sigma_h : sigma_v;
        imu_navcov_reset_state(&f->cov, POS + k, IMU_WMUL(sigma, sigma), 60, sat);
        f->carry[POS + k] = 0;
        if (fix->has_vel) {
            f->nav.vel[k] = fix->vel[k];
            imu_navcov_reset_state(&f->cov, VEL + k, IMU_WMUL(START_VEL, START_VEL), 60, sat);
            f->carry[VEL + k] = 0;
        }
    }
    imu_navcov_reset_state(&f->cov, BARO_BIAS, IMU_WMUL(START_BARO_BIAS, START_BARO_BIAS), 60, sat);
    f->carry[BARO_BIAS] = 0;
    f->baro_bias = 0;
    f->baro_reference = 0;
    if (fix->source == IMU_NAVKF_GNSS) {
        note_speed(f, fix);
        f->since_fix = 0;
    }
    f->anchored = 1;
    return 1;
}

imu_status_t imu_navkf_start(imu_navkf_t *f, imu_real_t rate, const imu_q16_t acc[3], const imu_real_t mag[3],
                             const imu_navkf_fix_t *fix, const imu_real_t lever_arm[3])
{
    uint32_t *sat;
    const imu_nav_origin_t nowhere = {UNANCHORED_LAT, 0, 0};
    imu_angle_t euler[3] = {0, 0, 0};
    imu_q30_t q[4];
    const imu_real_t still[3] = {0, 0, 0};
    imu_wide_t var[IMU_NAVKF_STATES];
    imu_q30_t sigma[IMU_NAVKF_STATES];
    int k;
    if (!(rate >= IMU_QCONST(10.0, 16) && rate <= IMU_QCONST(1000.0, 16)) ||
        !imu_tilt_from_acc(acc, &euler[0], &euler[1])) {
        return IMU_ERR_RANGE;
    }
    if (fix != 0 && !accuracies_in_range(fix)) {
        return IMU_ERR_RANGE;
    }
    for (k = 0; k < 3 && lever_arm != 0; ++k) {
        if (!(lever_arm[k] >= -MAX_LEVER_ARM_MM && lever_arm[k] <= MAX_LEVER_ARM_MM)) {
            return IMU_ERR_RANGE;
        }
    }
    euler[2] = imu_heading_from_mag(mag, euler[0], euler[1]);
    imu_euler_to_quat(euler, q);
    if (imu_nav_start(&f->nav, &nowhere, rate, q, still) != IMU_OK) {
        return IMU_ERR_RANGE;
    }
    sat = &f->nav.saturations;
    for (k = 0; k < 3; ++k) {
        /* mm * 2^40 / 1000 >> 20 -> m, Q20 */
        f->lever_arm[k] = lever_arm != 0 ? IMU_MUL(lever_arm[k], IMU_QCONST(0.001, 40), 20) : 0;
        f->rate[k] = 0;
    }
    for (k = 0; k < 3; ++k) {
        sigma[POS + k] = UNANCHORED_POS;
        sigma[VEL + k] = START_VEL;
        sigma[ATT + k] = k == 2 ? START_HEADING : START_TILT;
        sigma[GYRO_BIAS + k] = START_GYRO_BIAS;
        sigma[ACC_BIAS + k] = START_ACC_BIAS;
    }
    sigma[BARO_BIAS] = START_BARO_BIAS;
    for (k = 0; k < IMU_NAVKF_STATES; ++k) {
        var[k] = IMU_WMUL(sigma[k], sigma[k]); /* Q60 */
    }
    imu_navcov_init(&f->cov, IMU_NAVKF_STATES, var, 60, sat);
    f->dt_per_64 = IMU_MUL(f->nav.dt, IMU_QCONST(1.0 / 64.0, 36), 30); /* s Q30 -> s / 64, Q36 */
    f->cov_steps = seconds_in_steps(f, COV_INTERVAL);
    f->rest_steps = f->cov_steps;
    f->gap_steps = seconds_in_steps(f, GAP_TIME);
    f->longest_steps = seconds_in_steps(f, LONGEST_COUNT);
    f->still = 0;
    f->baro_bias = 0;
    f->baro_reference = 0;
    f->baro_steps = seconds_in_steps(f, BARO_INTERVAL);
    f->since_baro = f->baro_steps;
    f->sample_rate = rate;
    (void)imu_navkf_tune(f, &DEFAULT_TUNING);
    for (k = 0; k < IMU_NAVKF_STATES; ++k) {
        f->carry[k] = 0;
    }
    /* dt / tau, Q30: s Q30 * 2^16 / s Q16 (tau above dt) */
    f->fast_weight = IMU_DIV_SAT(f->nav.dt, TREND_FAST_TAU, 16, sat);
    f->slow_weight = IMU_DIV_SAT(f->nav.dt, TREND_SLOW_TAU, 16, sat);
    for (k = 0; k < 3; ++k) {
        f->force_fast[k] = f->force_slow[k] = acc[k];
    }
    f->since_fix = f->longest_steps; /* no GNSS yet: rest is the sensors' */
    f->fix_stood = 1;
    {
        imu_real_t norm = 0;
        imu_q30_t unit[3], earth[3], horizontal, r[3][3];
        f->field_reference = imu_vec3_normalize(mag, unit, &norm) ? norm : 0;
        f->dip_reference = 0;
        if (f->field_reference > 0) {
            matrix(f->nav.q, r);
            to_earth(r, unit, earth);
            f->dip_reference = imu_field_dip(earth, &horizontal);
        }
        f->dips_seen = 1;
        f->field_apart = f->field_away = f->field_after = 0;
        f->field_north = f->field_up = 0;
        f->field_turned = -1;
        imu_field_trust_reset(&f->field_trust);
    }
    for (k = 0; k < 3; ++k) {
        f->last_offset[k] = f->last_at[k] = f->last_vel[k] = 0;
        f->moved[k] = 0;
    }
    f->last_fix = 0;
    f->last_used = 0;
    f->fades = 0;
    f->spread = RAYLEIGH_MEAN;
    f->doubting = -1;
    f->resets = 0;
    f->rejected = 0;
    f->zero_velocity = 0;
    f->anchored = 0;
    restart_interval(f);
    if (fix != 0 && !anchor(f, fix)) {
        return IMU_ERR_RANGE;
    }
    return IMU_OK;
}

imu_status_t imu_navkf_tune(imu_navkf_t *f, const imu_navkf_tuning_t *tuning)
{
    const imu_navkf_tuning_t *t = tuning;
    if (!(t->gyro_noise > 0 && t->acc_noise > 0 && t->gyro_bias_walk > 0 && t->acc_bias_walk > 0 && t->gate > 0 &&
          t->reset_time > 0 && t->rest_rate > 0 && t->rest_force > 0 && t->acc_range > 0)) {
        return IMU_ERR_RANGE;
    }
    f->tuning = *t;
    /* densities (Q30) squared, Q60 >> 6 -> Q54; the velocity's in units of 64 m/s */
    f->noise_vel = IMU_WSHR(IMU_WMUL(IMU_MUL(t->acc_noise, IMU_QCONST(1.0 / 64.0, 30), 30),
                                     IMU_MUL(t->acc_noise, IMU_QCONST(1.0 / 64.0, 30), 30)), 6);
    f->noise_att = IMU_WSHR(IMU_WMUL(t->gyro_noise, t->gyro_noise), 6);
    f->noise_gyro_bias = IMU_WSHR(IMU_WMUL(t->gyro_bias_walk, t->gyro_bias_walk), 6);
    f->noise_acc_bias = IMU_WSHR(IMU_WMUL(t->acc_bias_walk, t->acc_bias_walk), 6);
    /* a sample's rate noise: the density over the sample rate's band, (rad^2/s Q54) * (Hz Q16)
     * = Q70 >> 10 -> (rad/s)^2, Q60 */
    f->zero_rate_var = IMU_WSHR(IMU_WMUL(f->noise_att, f->sample_rate), 10);
    f->reset_steps = seconds_in_steps(f, t->reset_time);
    /* A clipped sample's force lay anywhere beyond the full scale: its velocity step is
     * uncertain by about half the full scale times dt (m/s^2 Q16 / 128 -> half of it in
     * units of 64 m/s per s, * s Q30 >> 16 -> Q30), squared, Q60: a heel strike's clipped peak
     * then shows in the covariance, and the zero-velocity update after it takes back the
     * position it moved too (foot mounts: 6-12 g strikes on a +-8 g accelerometer). The
     * level: 1/64 below the full scale (a calibration scales it a little). */
    f->clip_level = IMU_SUB(t->acc_range, IMU_MUL(t->acc_range, IMU_QCONST(1.0 / 64.0, 30), 30));
    {
        const imu_q30_t half_step = IMU_MUL(IMU_MUL(t->acc_range, IMU_QCONST(1.0 / 128.0, 30), 30), f->nav.dt, 16);
        f->clip_var = IMU_WMUL(half_step, half_step);
    }
    return IMU_OK;
}

/** The specific force's low-passes; returns how steady it is, a weight in [0, 1] (Q30):
 *  1 while they agree, falling smoothly as they part. */
static imu_q30_t force_steadiness(imu_navkf_t *f, const imu_q16_t acc[3])
{
    uint32_t *sat = &f->nav.saturations;
    imu_q16_t trend = 0; /* the largest difference of the low-passes, m/s^2, Q16 */
    int k;
    for (k = 0; k < 3; ++k) {
        imu_q16_t d;
        f->force_fast[k] = IMU_ADD_SAT(f->force_fast[k], IMU_MUL(IMU_SUB_SAT(acc[k], f->force_fast[k], sat),
                                                                 f->fast_weight, 30), sat);
        f->force_slow[k] = IMU_ADD_SAT(f->force_slow[k], IMU_MUL(IMU_SUB_SAT(acc[k], f->force_slow[k], sat),
                                                                 f->slow_weight, 30), sat);
        d = IMU_SUB_SAT(f->force_fast[k], f->force_slow[k], sat);
        d = d < 0 ? IMU_NEG_SAT(d, sat) : d;
        trend = d > trend ? d : trend;
    }
    return imu_deviation_weight(IMU_SHL_SAT(trend, 8, sat), TREND_TOLERANCE, sat); /* Q16 -> Q24 */
}

/** 1 when the estimate's horizontal speed is below SLOW_SPEED. */
static int estimate_slow(const imu_navkf_t *f)
{
    const imu_real_t *v = f->nav.vel; /* m/s, Q20, within 512 m/s: the squares' sum below 2^59 */
    return IMU_WMUL(v[0], v[0]) + IMU_WMUL(v[1], v[1]) < IMU_WMUL(SLOW_SPEED, SLOW_SPEED);
}

void imu_navkf_step(imu_navkf_t *f, const imu_rate_t gyr[3], const imu_q16_t acc[3], const imu_real_t mag[3])
{
    const imu_q30_t steadiness = force_steadiness(f, acc);
    int k;
    for (k = 0; k < 3; ++k) {
        f->rate[k] = IMU_SUB_SAT(gyr[k], f->nav.gyro_bias[k], &f->nav.saturations);
    }
    for (k = 0; k < 3; ++k) {
        if (acc[k] >= f->clip_level || acc[k] <= -f->clip_level) {
            f->clipped_var += f->clip_var;
            break;
        }
    }
    f->still = still_sample(f, acc) ? (f->still < f->rest_steps ? f->still + 1 : f->still) : 0;
    f->since_fix += f->since_fix < f->longest_steps;
    f->since_baro += f->since_baro < f->baro_steps;
    f->doubting += f->doubting >= 0 && f->doubting < f->reset_steps;
    imu_nav_propagate(&f->nav, gyr, acc);
    for (k = 0; k < 3; ++k) {
        /* the specific force in ENU (the acceleration with gravity back), Q16 * Q36 -> Q52 */
        const imu_q16_t force = k == 2 ? IMU_ADD_SAT(f->nav.acc[2], IMU_SHR(f->nav.gravity, 8), &f->nav.saturations)
                                       : f->nav.acc[k];
        f->dv[k] += IMU_WMUL(force, f->dt_per_64);
    }
    if (++f->steps < f->cov_steps) {
        return;
    }
    flush(f);
    {
        /* GNSS within the last minute: rest as the last fix says while fixes come; through an
         * outage, only while the estimate's own speed is a walker's (a car cruising through a
         * tunnel is as still as a foot in its stance, but not as slow); without GNSS, the
         * sensors alone decide */
        const int with_gnss = f->since_fix < f->longest_steps;
        const int fixes_come = f->since_fix < f->gap_steps;
        const imu_q30_t w = with_gnss ? steadiness : IMU_ONE_Q30;
        const int at_rest_now = f->still >= f->rest_steps &&
                                (!with_gnss || (fixes_come ? f->fix_stood : estimate_slow(f))) && w > 0;
        if (at_rest_now) {
            at_rest(f, w);
        }
        if (!with_gnss) {
            gravity_tilt(f, acc); /* the attitude as an attitude filter keeps it */
        }
        if (mag != 0) {
            /* the heading from the field, at any speed: a fix's velocity shows the heading only
             * while the board accelerates, and a gyro bias that steps while it cruises would
             * turn it unseen; at rest weighed as the rest updates are */
            field_heading(f, mag, at_rest_now ? w : IMU_ONE_Q30);
        }
    }
}

/** z^2 / (P_ii + r) for the gate, Q16 (the gate's own saturations are not counted). */
static imu_real_t normalised_square(const imu_navkf_t *f, int i, imu_q30_t z, imu_wide_t r)
{
    uint32_t ignored = 0;
    imu_real_t s = IMU_ADD_SAT(imu_navcov_element_q30(&f->cov, i, i, &ignored),
                               IMU_WIDE_SAT(IMU_WSHR(r, 30), &ignored), &ignored); /* Q30 */
    if (s <= 0) {
        return 0; /* both below the Q30 resolution: nothing to gate on */
    }
    return IMU_DIV_SAT(IMU_MUL_SAT(z, z, 30, &ignored), s, 16, &ignored);
}

/** The normalised innovations squared of a fix's position and velocity (Q16; 0 without velocity),
 *  each axis against its own predicted variance plus the fix's (the correlations between the
 *  axes are small beside the fix's noise): the gate (the tuning's `gate`) rejects and counts a
 *  part beyond it and uses the other. */
static void gate_squares(imu_navkf_t *f, const imu_q30_t z[6], const imu_wide_t var[6], int has_vel, imu_real_t *pos,
                         imu_real_t *vel)
{
    uint32_t *sat = &f->nav.saturations;
    int k;
    *pos = *vel = 0;
    for (k = 0; k < 3; ++k) {
        *pos = IMU_ADD_SAT(*pos, normalised_square(f, POS + k, z[k], var[k]), sat);
        if (has_vel) {
            *vel = IMU_ADD_SAT(*vel, normalised_square(f, VEL + k, z[3 + k], var[3 + k]), sat);
        }
    }
}

/** A value (mm) over a standard deviation (mm, >= 1), Q16 (saturated: the gate's own saturations are not counted). */
static imu_real_t in_sigmas(imu_real_t value, imu_real_t sigma)
{
    uint32_t ignored = 0;
    return IMU_DIV_SAT(value, sigma, 16, &ignored);
}

/**
 * How far a GNSS fix lies from the last one moved to its time (Q16, in standard deviations of
 * their difference: horizontal h_acc each axis, vertical v_acc sqrt 2), by the receiver's mean
 * velocity when both have one, else by the estimate's displacement without the corrections
 * applied since (`offset`: this fix's offset from the estimate, mm); *horizontal gets the
 * horizontal part. -1 when there is none to compare with (none yet, or too long ago).
 */
static imu_real_t disagreement(const imu_navkf_t *f, const imu_navkf_fix_t *fix, const imu_real_t at_fix[3],
                               const imu_real_t offset[3], imu_real_t *horizontal)
{
    uint32_t ignored = 0;
    const imu_nav_t *n = &f->nav;
    imu_real_t d[3]; /* mm */
    int k;
    if (f->last_fix == 0 || f->since_fix > f->gap_steps) {
        return -1;
    }
    for (k = 0; k < 3; ++k) {
        if (fix->has_vel && f->last_fix == 2) {
            /* mean velocity (Q20; the sum saturates: a velocity may lie at the type's limit) * dt (Q30)
               >> 30 -> m per sample, Q20; * samples * 1000 >> 20 -> mm */
            const imu_real_t per_sample = IMU_MUL(IMU_HALF(IMU_ADD_SAT(fix->vel[k], f->last_vel[k], &ignored)), n->dt, 30);
            const imu_real_t moved = IMU_WIDE_SAT(IMU_WSHR(IMU_WMUL(per_sample, f->since_fix) * 1000, 20), &ignored);
            d[k] = IMU_SUB_SAT(IMU_SUB_SAT(at_fix[k], f->last_at[k], &ignored), IMU_MUL_SAT(moved, k == 0 ? n->scale_east
                               : k == 1 ? n->scale_north : IMU_ONE_Q30, 30, &ignored), &ignored); /* offset mm */
            if (k < 2) {
                d[k] = IMU_DIV_SAT(d[k], k == 0 ? n->scale_east : n->scale_north, 30, &ignored); /* mm */
            }
        } else {
            d[k] = IMU_ADD_SAT(IMU_SUB_SAT(offset[k], f->last_offset[k], &ignored), f->moved[k], &ignored);
        }
    }
    *horizontal = imu_hypot(in_sigmas(d[0], fix->h_acc), in_sigmas(d[1], fix->h_acc));
    return imu_hypot(*horizontal, in_sigmas(d[2], IMU_MUL_SAT(fix->v_acc, IMU_QCONST(1.41421356, 30), 30, &ignored)));
}

/** The receiver's accuracy's inflation (Q16, at least 1): how far its fixes disagree among
 *  themselves beside what their accuracies say. */
static imu_real_t inflation(const imu_navkf_t *f)
{
    uint32_t ignored = 0;
    return f->spread > RAYLEIGH_MEAN ? IMU_DIV_SAT(f->spread, RAYLEIGH_MEAN, 16, &ignored) : IMU_QCONST(1.0, 16);
}

/** The estimate in doubt: position (and velocity) reset to the fix, as at the start. */
static int reset_to_fix(imu_navkf_t *f, const imu_navkf_fix_t *fix)
{
    if (!anchor(f, fix)) {
        return 0;
    }
    ++f->resets;
    f->doubting = -1;
    f->last_fix = 0;
    return 1;
}

int imu_navkf_fix(imu_navkf_t *f, const imu_navkf_fix_t *fix)
{
    uint32_t *sat = &f->nav.saturations;
    imu_nav_t *n = &f->nav;
    imu_real_t at_fix[3], arm_enu[3], arm_vel[3]; /* offsets mm; the antenna's velocity beside the sensor's, Q20 */
    imu_real_t offset[3];                         /* the fix's offset from the estimate then, ENU, mm */
    imu_q30_t z[6], dx[IMU_NAVKF_STATES], r[3][3];
    imu_wide_t var[6]; /* the measurements' variances, Q60 */
    imu_real_t nis_pos = 0, nis_vel = 0, apart = -1, apart_h = 0; /* Q16 */
    int agrees = 0; /* the fix agrees with the last one (within GATE_SIGMAS, inflated) */
    const int gnss = fix->source == IMU_NAVKF_GNSS;
    const imu_real_t gate = f->tuning.gate; /* Q16 */
    const imu_real_t inflate = gnss ? inflation(f) : IMU_QCONST(1.0, 16);
    /* standard deviations in the states' units, Q30: horizontal (each axis), vertical, speed */
    const imu_q30_t sigma_pos[2] = {IMU_MUL_SAT(IMU_MUL_SAT(fix->h_acc, MM_TO_POS_AXIS, 20, sat), inflate, 16, sat),
                                    IMU_MUL_SAT(IMU_MUL_SAT(fix->v_acc, MM_TO_POS, 20, sat), inflate, 16, sat)};
    const imu_q30_t sigma_vel = IMU_MUL_SAT(fix->s_acc, MM_S_TO_VEL, 16, sat);
    int use_pos, use_vel, k;
    if (!f->anchored) {
        return anchor(f, fix);
    }
    if (!accuracies_in_range(fix)) {
        return 0;
    }
    flush(f);
    imu_nav_offsets(n, fix->lat, fix->lon, fix->height, at_fix);
    matrix(n->q, r); /* the attitude until the corrections are applied */
    antenna_offset(f, r, arm_enu);
    antenna_velocity(f, r, arm_vel);
    for (k = 0; k < 3; ++k) {
        /* where the estimate was when the fix was valid: back by v age (Q20 * Q30 >> 20 -> m
         * Q30, * 1000 >> 30 -> mm) and by a age for the velocity (Q16 * Q30 >> 26 -> Q20) */
        const imu_real_t back = IMU_WIDE_SAT(IMU_WSHR(IMU_WSHR(IMU_WMUL(n->vel[k], fix->age), 20) * 1000, 30), sat);
        imu_real_t d = IMU_SUB_SAT(at_fix[k], IMU_SUB_SAT(n->pos[k], back, sat), sat); /* offset mm */
        if (k < 2) {
            d = IMU_DIV_SAT(d, k == 0 ? n->scale_east : n->scale_north, 30, sat); /* offset mm -> mm */
        }
        offset[k] = IMU_SUB_SAT(d, arm_enu[k], sat);
        z[k] = IMU_MUL_SAT(offset[k], MM_TO_POS, 20, sat);
        var[k] = IMU_WMUL(sigma_pos[k < 2 ? 0 : 1], sigma_pos[k < 2 ? 0 : 1]);
        if (fix->has_vel) {
            const imu_real_t back_vel = IMU_WIDE_SAT(IMU_WSHR(IMU_WMUL(n->acc[k], fix->age), 26), sat);
            const imu_real_t was = IMU_ADD_SAT(IMU_SUB_SAT(n->vel[k], back_vel, sat), arm_vel[k], sat);
            z[3 + k] = velocity_units(IMU_SUB_SAT(fix->vel[k], was, sat), sat);
            var[3 + k] = IMU_WMUL(sigma_vel, sigma_vel);
        }
    }
    use_pos = 1;
    use_vel = fix->has_vel;
    if (gnss) {
        gate_squares(f, z, var, fix->has_vel, &nis_pos, &nis_vel);
        apart = disagreement(f, fix, at_fix, offset, &apart_h);
        agrees = apart >= 0 && apart <= IMU_MUL(GATE_SIGMAS, inflate, 16);
        if ((nis_pos > gate || nis_vel > gate) && f->last_used && agrees) {
            /* A fix that agrees with the last one used but not with the estimate: the estimate
             * is the one in doubt (a gyro bias that stepped, a model the motion left): its
             * covariance is scaled up, a doubling at a time, until the fix passes, a fading
             * memory (counted). */
            int doubled[IMU_NAVKF_STATES]; /* each state's standard deviation doubled once more, or not */
            const int position_in_doubt = nis_pos > gate; /* else only what the velocity depends on */
            int fade;
            for (fade = 1; fade <= MAX_FADE && (nis_pos > gate || nis_vel > gate); ++fade) {
                for (k = 0; k < IMU_NAVKF_STATES; ++k) {
                    doubled[k] = (k >= VEL || position_in_doubt) && !(k >= ATT && k < ATT + 3 && fade > ATTITUDE_FADE);
                }
                imu_navcov_scale_up(&f->cov, doubled);
                gate_squares(f, z, var, fix->has_vel, &nis_pos, &nis_vel);
            }
            for (k = 0; k < 3; ++k) {
                imu_navcov_cap_unit_variance(&f->cov, ATT + k);
            }
            ++f->fades;
        }
        use_pos = nis_pos <= gate;
        use_vel = fix->has_vel && nis_vel <= gate;
        if (apart >= 0) {
            /* the receiver's own consistency, an outlier counted as SPREAD_CAP at most */
            f->spread = IMU_ADD(f->spread, IMU_MUL(IMU_SUB(apart_h < SPREAD_CAP ? apart_h : SPREAD_CAP, f->spread),
                                                   SPREAD_WEIGHT, 30));
        }
        for (k = 0; k < 3; ++k) {
            f->last_offset[k] = offset[k];
            f->last_at[k] = at_fix[k];
            f->last_vel[k] = fix->vel[k];
            f->moved[k] = 0;
        }
        f->last_fix = fix->has_vel ? 2 : 1;
        f->last_used = use_pos;
        /* whether the board stands, from any fix: a rejected one's position is in doubt, not its speed */
        note_speed(f, fix);
        f->since_fix = 0;
        if (!use_pos || use_vel != fix->has_vel) {
            ++f->rejected;
            if (f->doubting >= 0 && agrees) {
                /* a run of rejected fixes that agree with each other: the estimate is in doubt */
                if (f->doubting >= f->reset_steps) {
                    return reset_to_fix(f, fix);
                }
            } else {
                f->doubting = 0;
            }
        } else {
            f->doubting = -1;
        }
    }
    clear(dx);
    for (k = 0; k < 6; ++k) {
        imu_q30_t h[IMU_NAVKF_STATES];
        if (k < 3 ? !use_pos : !use_vel) {
            continue;
        }
        clear(h);
        h[k] = IMU_ONE_Q30;
        if (k < 3) {
            lever_arm_row(f, r[k], &h[ATT]);
        }
        /* A receiver's position with its velocity corrects neither the attitude nor the gyro
         * bias: its errors wander for tens of seconds (multipath) where its Doppler velocity's
         * do not, and the velocity shows the heading. */
        measure_row(f, h, z[k], var[k], IMU_ONE_Q30, k < 3 && gnss && fix->has_vel ? &POSITION_ONLY : NULL, dx);
    }
    apply(f, dx);
    return use_pos && use_vel == fix->has_vel;
}

/** ln(1 + u) for |u| <= BARO_REFERENCE_SPAN, Q30: u - u^2/2 + u^3/3 - u^4/4. */
static imu_q30_t log1p_series(imu_q30_t u)
{
    const imu_q30_t u2 = IMU_MUL(u, u, 30), u3 = IMU_MUL(u2, u, 30), u4 = IMU_MUL(u2, u2, 30);
    return IMU_SUB(IMU_ADD(IMU_SUB(u, IMU_HALF(u2)), IMU_MUL(u3, IMU_QCONST(1.0 / 3.0, 30), 30)),
                   IMU_MUL(u4, IMU_QCONST(0.25, 30), 30));
}

/** The height (mm) of a pressure (Pa) against the reference: h0 - H ln(p / p0). */
static imu_real_t baro_height(const imu_navkf_t *f, imu_real_t pressure)
{
    uint32_t ignored = 0; /* within the span: |u| <= 0.05 + a pascal */
    const imu_q30_t u = IMU_DIV_SAT(IMU_SUB(pressure, f->baro_reference), f->baro_reference, 30, &ignored);
    const imu_real_t h = IMU_SUB(SCALE_HEIGHT_SEA_MM, IMU_MUL(f->baro_reference_height, SCALE_HEIGHT_PER_MM, 30));
    /* Q30 * mm >> 30 -> mm; |H ln| below 0.06 * 8.5e6 */
    return IMU_SUB_SAT(f->baro_reference_height, IMU_WIDE_SAT(IMU_WSHR(IMU_WMUL(log1p_series(u), h), 30), &ignored),
                       &ignored);
}

void imu_navkf_baro(imu_navkf_t *f, imu_real_t pressure)
{
    uint32_t *sat = &f->nav.saturations;
    imu_nav_t *n = &f->nav;
    const imu_real_t estimate = IMU_ADD_SAT(n->origin.height, n->pos[2], sat); /* mm */
    imu_real_t height;
    if (!f->anchored || !(pressure >= BARO_MIN_PA && pressure <= BARO_MAX_PA)) {
        return;
    }
    if (f->baro_reference == 0) {
        f->baro_reference = pressure;
        f->baro_reference_height = estimate;
    }
    {
        uint32_t ignored = 0;
        const imu_q30_t u = IMU_DIV_SAT(IMU_SUB(pressure, f->baro_reference), f->baro_reference, 30, &ignored);
        if (u > 2 * BARO_REFERENCE_SPAN || u < -2 * BARO_REFERENCE_SPAN) {
            return; /* a jump of 800 m between two samples: not the air's pressure */
        }
        if (u > BARO_REFERENCE_SPAN || u < -BARO_REFERENCE_SPAN) {
            /* a new reference at this sample, at the height the old one gives it (the series
             * stays within its span however far the board climbs) */
            f->baro_reference_height = baro_height(f, pressure);
            f->baro_reference = pressure;
        }
    }
    if (f->since_baro < f->baro_steps) {
        return;
    }
    height = baro_height(f, pressure);
    flush(f);
    {
        /* z = h_baro - (h + b): the height's and the bias's errors, each in units of 1024 m */
        imu_q30_t h[IMU_NAVKF_STATES], dx[IMU_NAVKF_STATES];
        const imu_real_t d = IMU_SUB_SAT(IMU_SUB_SAT(height, estimate, sat), f->baro_bias, sat); /* mm */
        clear(h);
        clear(dx);
        h[POS + 2] = IMU_ONE_Q30;
        h[BARO_BIAS] = IMU_ONE_Q30;
        (void)imu_navcov_update(&f->cov, h, IMU_WMUL(BARO_SIGMA, BARO_SIGMA), 60, IMU_MUL_SAT(d, MM_TO_POS, 20, sat),
                                IMU_ONE_Q30, NULL, dx, sat);
        apply(f, dx);
    }
    f->since_baro = 0;
}

void imu_navkf_position(const imu_navkf_t *f, imu_angle_t *lat, imu_angle_t *lon, imu_real_t *height)
{
    const imu_nav_t *n = &f->nav;
    uint32_t ignored = 0;
    *lat = imu_nav_latitude(n);
    /* east offset (mm) * rad per mm (Q59) >> 30 -> Q29, wrapped */
    *lon = imu_angle_add(n->origin.lon, IMU_MUL_SAT(n->pos[0], n->lon_per_mm, 30, &ignored));
    *height = IMU_ADD_SAT(n->origin.height, n->pos[2], &ignored);
}

void imu_navkf_variance(const imu_navkf_t *f, int i, imu_real_t *mant, int32_t *exp)
{
    imu_navcov_get(&f->cov, i, i, mant, exp);
}
