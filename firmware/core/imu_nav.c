/**
 * @file imu_nav.c
 * @brief Strapdown navigation on the WGS-84 ellipsoid (see imu_nav.h).
 */
#include "imu_nav.h"

#include "imu_math.h"

/* WGS-84 (NIMA TR8350.2): semi-major axis, first eccentricity squared, flattening,
 * m = omega^2 a^2 b / GM, normal gravity at the equator, Somigliana's constant
 * k = b gamma_p / (a gamma_e) - 1. */
#define WGS84_A_MM 6378137000.0
#define WGS84_E2 6.69437999014e-3
#define WGS84_F (1.0 / 298.257223563)
#define WGS84_M 0.00344978650684
#define WGS84_GAMMA_E 9.7803253359
#define WGS84_K 1.931852652458e-3

/** 1/a in rad per mm, Q59 (9.04e7), and in 1/mm, Q61 (3.6e8, for h / a). */
#define INV_A_MM_Q59 IMU_QCONST(1.0 / WGS84_A_MM, 59)
#define INV_A_MM_Q61 IMU_QCONST(1.0 / WGS84_A_MM, 61)

/** +-85 deg: beyond, the east scale ((N0 + h0) cos lat0) / ((N + h) cos lat) leaves Q30. */
#define MAX_LATITUDE IMU_QCONST(1.4835298641951802, 29)
#define MAX_LONGITUDE IMU_QCONST(3.14159265358979323846, 29)
#define MAX_ORIGIN_HEIGHT_MM IMU_QCONST(10000000.0, 0)
/** The geometry takes heights within +-1000 km (an open vertical channel may run further):
 *  |h / a| < 0.16 keeps the free-air factor in [0.7, 1.4] and (M + h) / a above 0.8. */
#define MAX_GEOMETRY_HEIGHT_MM IMU_QCONST(1000000000.0, 0)
#define MAX_SPEED IMU_QCONST(IMU_NAV_MAX_SPEED, 20)
/** The largest specific force the step takes, m/s^2, Q16 (2^29: 8 192 m/s^2, fifty times a
 *  +-16 g accelerometer's range): turned by up to a radian (theta / 2, theta saturated at
 *  2 rad), it stays within int32. */
#define MAX_FORCE IMU_QCONST(8192.0, 16)

/**
 * The ellipsoid at a latitude (sine and cosine, Q30) and a height (mm): (M + h) / a and
 * (N + h) cos(lat) / a (Q30), and normal gravity (m/s^2, Q24).
 *
 * With w = e^2 sin^2(lat) (at most 6.7e-3), 1 / sqrt(1 - w) = 1 + w/2 + 3 w^2 / 8 to
 * 5 w^3 / 16 (1e-7: 0.6 m of radius, 1e-6 m/s^2 of gravity), the same series in both
 * builds: N / a = 1 / sqrt(1 - w), M / a = (1 - e^2) / sqrt(1 - w)^3, Somigliana's gravity
 * gamma_e (1 + k sin^2) / sqrt(1 - w) and its second-order free-air correction
 * 1 - 2 (1 + f + m - 2 f sin^2) h / a + 3 (h / a)^2 (TR8350.2 eq. 4-1 and 4-3).
 */
static void ellipsoid(imu_q30_t s, imu_q30_t c, imu_real_t height_mm, imu_q30_t *rm, imu_q30_t *rn_cos,
                      imu_real_t *gravity)
{
    const imu_q30_t s2 = IMU_MUL(s, s, 30);
    const imu_q30_t w = IMU_MUL(IMU_QCONST(WGS84_E2, 30), s2, 30);
    /* 1 / sqrt(1 - w), Q30, below 1.004 */
    const imu_q30_t inv_root = IMU_ADD(IMU_ADD(IMU_ONE_Q30, IMU_HALF(w)),
                                       IMU_MUL(IMU_MUL(w, w, 30), IMU_QCONST(0.375, 30), 30));
    const imu_q30_t inv_root3 = IMU_MUL(IMU_MUL(inv_root, inv_root, 30), inv_root, 30);
    /* h / a: mm (|h| <= 10^9) * Q61 >> 31 -> Q30, |h / a| < 0.16 */
    const imu_q30_t ha = IMU_MUL(height_mm, INV_A_MM_Q61, 31);
    /* 2 (1 + f + m - 2 f sin^2), Q29 (about 2.014): Q30 * Q30 >> 31 -> Q29 */
    const imu_real_t t = IMU_SUB(IMU_QCONST(2.0 * (1.0 + WGS84_F + WGS84_M), 29),
                                 IMU_MUL(IMU_QCONST(4.0 * WGS84_F, 30), s2, 31));
    const imu_q30_t free_air = IMU_ADD(IMU_SUB(IMU_ONE_Q30, IMU_MUL(t, ha, 29)),
                                       IMU_MUL(IMU_QCONST(3.0, 28), IMU_MUL(ha, ha, 30), 28));
    const imu_real_t somigliana =
        IMU_MUL(IMU_MUL(IMU_QCONST(WGS84_GAMMA_E, 24), IMU_ADD(IMU_ONE_Q30, IMU_MUL(IMU_QCONST(WGS84_K, 30), s2, 30)),
                        30),
                inv_root, 30); /* Q24 */
    *rm = IMU_ADD(IMU_MUL(IMU_QCONST(1.0 - WGS84_E2, 30), inv_root3, 30), ha);
    *rn_cos = IMU_MUL(IMU_ADD(inv_root, ha), c, 30);
    *gravity = IMU_MUL(somigliana, free_air, 30);
}

imu_angle_t imu_nav_latitude(const imu_nav_t *n)
{
    /* north offset (mm, int32) * rad per mm (Q59) >> 30 -> Q29: within +-0.34 rad of the origin */
    return IMU_ADD(n->origin.lat, IMU_MUL(n->pos[1], n->lat_per_mm, 30));
}

/** The scales and gravity at the current position. */
static void update_geometry(imu_nav_t *n)
{
    imu_angle_t lat = imu_nav_latitude(n);
    imu_real_t height = IMU_ADD_SAT(n->origin.height, n->pos[2], &n->saturations);
    imu_q30_t s, c, rm, rn_cos;
    if (lat > MAX_LATITUDE) {
        lat = MAX_LATITUDE;
    } else if (lat < -MAX_LATITUDE) {
        lat = -MAX_LATITUDE;
    }
    if (height > MAX_GEOMETRY_HEIGHT_MM) {
        height = MAX_GEOMETRY_HEIGHT_MM;
    } else if (height < -MAX_GEOMETRY_HEIGHT_MM) {
        height = -MAX_GEOMETRY_HEIGHT_MM;
    }
    imu_sincos(lat, &s, &c);
    ellipsoid(s, c, height, &rm, &rn_cos, &n->gravity);
    /* both ratios near 1 within +-85 deg and +-2000 km: saturated at 2 beyond */
    n->scale_north = IMU_DIV_SAT(n->origin_rm, rm, 30, &n->saturations);
    n->scale_east = IMU_DIV_SAT(n->origin_rn_cos, rn_cos, 30, &n->saturations);
}

static int origin_in_range(const imu_nav_origin_t *origin)
{
    return origin->lat <= MAX_LATITUDE && origin->lat >= -MAX_LATITUDE && origin->lon <= MAX_LONGITUDE &&
           origin->lon >= -MAX_LONGITUDE && origin->height <= MAX_ORIGIN_HEIGHT_MM &&
           origin->height >= -MAX_ORIGIN_HEIGHT_MM;
}

imu_status_t imu_nav_start(imu_nav_t *n, const imu_nav_origin_t *origin, imu_real_t rate, const imu_q30_t q[4],
                           const imu_real_t vel[3])
{
    int k;
    if (!(rate >= IMU_QCONST(10.0, 16) && rate <= IMU_QCONST(IMU_Q16_LARGEST, 16)) || !origin_in_range(origin)) {
        return IMU_ERR_RANGE;
    }
    for (k = 0; k < 3; ++k) {
        if (!(vel[k] <= MAX_SPEED && vel[k] >= -MAX_SPEED)) {
            return IMU_ERR_RANGE;
        }
    }
    n->saturations = 0;
    /* 2^46 / rate (Q16): below 2^31 from 10 Hz on */
    n->dt = IMU_DIV_SAT(IMU_QCONST(1.0, 16), rate, 30, &n->saturations);
    for (k = 0; k < 4; ++k) {
        n->q[k] = q[k];
    }
    imu_quat_normalize(n->q);
    for (k = 0; k < 3; ++k) {
        n->vel[k] = vel[k];
        n->gyro_bias[k] = 0;
        n->acc_bias[k] = 0;
        n->acc[k] = 0;
        n->vel_carry[k] = 0;
        n->theta_prev[k] = 0;
        n->force_prev[k] = 0;
    }
    return imu_nav_anchor(n, origin);
}

imu_status_t imu_nav_anchor(imu_nav_t *n, const imu_nav_origin_t *origin)
{
    imu_q30_t s, c;
    imu_real_t gravity;
    int k;
    if (!origin_in_range(origin)) {
        return IMU_ERR_RANGE;
    }
    n->origin = *origin;
    imu_sincos(origin->lat, &s, &c);
    ellipsoid(s, c, origin->height, &n->origin_rm, &n->origin_rn_cos, &gravity);
    /* rad per mm: (1 / a) / ((M0 + h0) / a), Q59 * 2^30 / Q30 -> Q59 */
    n->lat_per_mm = IMU_DIV_SAT(INV_A_MM_Q59, n->origin_rm, 30, &n->saturations);
    n->lon_per_mm = IMU_DIV_SAT(INV_A_MM_Q59, n->origin_rn_cos, 30, &n->saturations);
    for (k = 0; k < 3; ++k) {
        n->pos[k] = 0;
        n->pos_carry[k] = 0;
    }
    update_geometry(n);
    return IMU_OK;
}

/** A horizontal step's largest part scaled at once: 65.5 m in Q15 mm (2^31), so that the
 *  part times a scale (below 2^31) stays below 2^62. A propagation step is at most 51.2 m;
 *  a correction (up to 2 km) is moved in parts. */
#define MOVE_PART ((imu_wide_t)IMU_QCONST(32768.0, 15) * 2)

/** The position moved by `step` (ENU, mm, Q15), the offsets scaled to the origin's radii,
 *  each rounding carried to the next. */
static void move(imu_nav_t *n, const imu_wide_t step[3])
{
    uint32_t *sat = &n->saturations;
    int k;
    for (k = 0; k < 3; ++k) {
        if (k == 2) {
            n->pos[2] = IMU_ADD_SAT(n->pos[2], IMU_WSHR_FEEDBACK_SAT(step[2], 15, &n->pos_carry[2], sat), sat);
        } else {
            /* Q15 mm * Q30 scale (below 2) = Q45 mm, below 2^62 a part, >> 45 -> mm */
            const imu_q30_t scale = k == 0 ? n->scale_east : n->scale_north;
            imu_wide_t left = step[k];
            do {
                const imu_wide_t part = left > MOVE_PART ? MOVE_PART : (left < -MOVE_PART ? -MOVE_PART : left);
                n->pos[k] = IMU_ADD_SAT(n->pos[k], IMU_WSHR_FEEDBACK_SAT(part * scale, 45, &n->pos_carry[k], sat),
                                        sat);
                left -= part;
            } while (left != 0);
        }
    }
}

void imu_nav_move(imu_nav_t *n, const imu_wide_t step[3])
{
    move(n, step);
    update_geometry(n);
}

void imu_nav_offsets(imu_nav_t *n, imu_angle_t lat, imu_angle_t lon, imu_real_t height, imu_real_t out[3])
{
    uint32_t *sat = &n->saturations;
    /* rad (Q29) * 2^30 / rad per mm (Q59) -> mm; the longitude difference wrapped to +-pi */
    out[0] = IMU_DIV_SAT(imu_angle_diff(lon, n->origin.lon), n->lon_per_mm, 30, sat);
    out[1] = IMU_DIV_SAT(IMU_SUB_SAT(lat, n->origin.lat, sat), n->lat_per_mm, 30, sat);
    out[2] = IMU_SUB_SAT(height, n->origin.height, sat);
}

/** (a x b)_k / 12 for a of Q30 (|a| < 2) and b of any Q format (|b| below 2^31): in b's
 *  format. Each product is below 2^62; they are halved twice before the difference. */
static imu_real_t twelfth_cross(const imu_q30_t a[3], const imu_real_t b[3], int k)
{
    const int i = (k + 1) % 3, j = (k + 2) % 3;
    const imu_wide_t d = IMU_WSHR(IMU_WMUL(a[i], b[j]), 2) - IMU_WSHR(IMU_WMUL(a[j], b[i]), 2); /* Q(b + 28) */
    /* >> 28 -> b's format (below 2^33), * 1/12 (Q30) >> 30 */
    return IMU_NARROW(IMU_WSHR(IMU_WSHR(d, 28) * IMU_QCONST(1.0 / 12.0, 30), 30)); /* below 2^30 in b's format */
}

void imu_nav_propagate(imu_nav_t *n, const imu_rate_t gyr[3], const imu_q16_t acc[3])
{
    uint32_t *sat = &n->saturations;
    imu_q30_t theta[3], phi[3], half_back[3], row[3];
    imu_q16_t raw[3];    /* the sample's specific force, bias-corrected, m/s^2, Q16 */
    imu_q16_t f[3];      /* specific force at the middle of the turn, sensor frame, m/s^2, Q16 */
    imu_q16_t a[3];      /* acceleration, ENU, m/s^2, Q16 */
    imu_real_t vel[3];   /* the new velocity, Q20 */
    imu_wide_t step[3];  /* the position's step, mm, Q15 */
    int k;
    for (k = 0; k < 3; ++k) {
        /* rad/s Q24 * s Q30 >> 24 -> rad Q30 */
        theta[k] = IMU_MUL_SAT(IMU_SUB_SAT(gyr[k], n->gyro_bias[k], sat), n->dt, 24, sat);
        half_back[k] = IMU_NEG_SAT(IMU_HALF(theta[k]), sat);
        raw[k] = IMU_SUB_SAT(acc[k], n->acc_bias[k], sat);
        if (raw[k] > MAX_FORCE || raw[k] < -MAX_FORCE) {
            raw[k] = raw[k] > 0 ? MAX_FORCE : -MAX_FORCE; /* no accelerometer's: held, counted */
            ++*sat;
        }
    }
    /* Coning and sculling, to second order in a rate and a force that vary linearly over
     * two samples (the increments are interval means): the rotation vector theta + (theta'
     * x theta) / 12 and the force f + (theta' x f + f' x theta) / 12, the primes the last
     * sample's. (Exact for rates constant over each interval, the simulator's, up to these
     * terms: some 1e-8 rad a sample in a car.) */
    for (k = 0; k < 3; ++k) {
        phi[k] = IMU_ADD_SAT(theta[k], twelfth_cross(n->theta_prev, theta, k), sat);
        f[k] = IMU_ADD_SAT(raw[k], IMU_ADD_SAT(twelfth_cross(n->theta_prev, raw, k),
                                                -twelfth_cross(theta, n->force_prev, k), sat), sat);
        if (f[k] > MAX_FORCE || f[k] < -MAX_FORCE) {
            f[k] = f[k] > 0 ? MAX_FORCE : -MAX_FORCE;
            ++*sat;
        }
    }
    for (k = 0; k < 3; ++k) {
        n->theta_prev[k] = theta[k];
        n->force_prev[k] = raw[k];
    }
    /* The sample is the specific force's mean over the turn, in the turning frame: seen
     * from the frame at the interval's start it is, to first order, the force at the
     * middle of the turn, f + (theta / 2) x f (an accelerometer sampled at the end of a
     * steady turn would read the force turned by theta / 2 short). |f| below 2^29. */
    imu_vec3_turn_back(f, half_back);
    for (k = 0; k < 3; ++k) {
        /* rows of R (Q30, unit) times f (Q16) >> 30 -> Q16 */
        imu_quat_matrix_row(n->q, k, row);
        a[k] = IMU_ADD_SAT(IMU_ADD_SAT(IMU_MUL(row[0], f[0], 30), IMU_MUL(row[1], f[1], 30), sat),
                           IMU_MUL(row[2], f[2], 30), sat);
    }
    a[2] = IMU_SUB_SAT(a[2], IMU_SHR(n->gravity, 8), sat); /* gravity Q24 -> Q16 */
    imu_quat_integrate(n->q, phi);
    for (k = 0; k < 3; ++k) {
        /* a (Q16) dt (Q30) -> Q46 >> 26 -> Q20, the rounding carried */
        vel[k] = IMU_ADD_SAT(n->vel[k], IMU_WSHR_FEEDBACK_SAT(IMU_WMUL(a[k], n->dt), 26, &n->vel_carry[k], sat),
                             sat);
        if (vel[k] > MAX_SPEED) {
            vel[k] = MAX_SPEED;
            ++*sat;
        } else if (vel[k] < -MAX_SPEED) {
            vel[k] = -MAX_SPEED;
            ++*sat;
        }
    }
    for (k = 0; k < 3; ++k) {
        /* The step's metres, the trapezoid (v + v') dt / 2: (Q20 + Q20) * Q30 = Q50 (at
         * most 2^30 * 2^26.7), >> 25 -> Q25 m twice the step; * 500 -> Q25 mm the step,
         * >> 10 -> Q15 mm (at most 2^30.7 at 512 m/s and 10 Hz). */
        step[k] = IMU_WSHR(IMU_WSHR(((imu_wide_t)n->vel[k] + vel[k]) * n->dt, 25) * 500, 10);
        n->vel[k] = vel[k];
        n->acc[k] = a[k];
    }
    move(n, step);
    update_geometry(n);
}
