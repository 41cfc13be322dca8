/* Drives imu_navkf.c for tests/test_navkf.py: reads from stdin the sample rate (Hz), then
 * one record per line until EOF:
 *   b lat_deg lon_deg height_m vel_e vel_n vel_u h_acc_m v_acc_m s_acc_m_s has_vel ax ay az mx my mz
 *     start at a GNSS fix (then the accelerometer and magnetometer at rest), once, first;
 *     "k" instead of "b": start at a known place (a marker: no GNSS);
 *   s gx gy gz ax ay az mx my mz   an IMU sample (rad/s, m/s^2, uT; 0 0 0: no field): prints the state after it,
 *     "lat_deg lon_deg height_m vel_e vel_n vel_u qw qx qy qz" and the 16 standard
 *     deviations of the error state in SI units (m, m/s, rad, rad/s, m/s^2, m);
 *   f lat_deg lon_deg height_m vel_e vel_n vel_u h_acc_m v_acc_m s_acc_m_s has_vel age_s
 *     a GNSS fix (has_vel 0: without velocity);
 *   m lat_deg lon_deg height_m 0 0 0 h_acc_m v_acc_m 1 0 age_s   a marker's position fix;
 *   p pressure_pa              a barometer sample.
 * At the end: "rejected N zero_velocity N saturations N". Built twice, with -DIMU_FIXED
 * (and -DIMU_CHECK_NARROWING) and -DIMU_FLOAT. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "imu_navkf.h"

#include "narrowing_abort.h"

#ifdef IMU_FIXED
#define TO_Q(x, q) ((int32_t)llrint((x) * ldexp(1.0, (q)))) /* half to even, as numpy and imulink.nav round */
#define FROM_Q(x, q) ((double)(x) * ldexp(1.0, -(q)))
#define VAR_Q 30 /* P_ii = mant 2^(exp - VAR_Q) */
#else
#define VAR_Q 0
#define TO_Q(x, q) (x)
#define FROM_Q(x, q) (x)
#endif

static const double DEG = 3.14159265358979323846 / 180.0;
/* the error states' units (imu_navkf.h) */
static const double UNIT[IMU_NAVKF_STATES] = {1024, 1024, 1024, 64, 64, 64, 1, 1, 1, 1, 1, 1, 1, 1, 1, 1024};

static int read_fix(imu_navkf_fix_t *fix, int with_age)
{
    double lat, lon, h, v[3], hacc, vacc, sacc, age = 0.0;
    int has_vel, k;
    if (scanf("%lf %lf %lf %lf %lf %lf %lf %lf %lf %d", &lat, &lon, &h, &v[0], &v[1], &v[2], &hacc, &vacc, &sacc,
              &has_vel) != 10 ||
        (with_age && scanf("%lf", &age) != 1)) {
        return 0;
    }
    fix->lat = TO_Q(lat * DEG, 29);
    fix->lon = TO_Q(lon * DEG, 29);
    fix->height = TO_Q(h * 1000.0, 0);
    for (k = 0; k < 3; ++k) {
        fix->vel[k] = TO_Q(v[k], 20);
    }
    fix->has_vel = has_vel;
    fix->h_acc = TO_Q(hacc * 1000.0, 0);
    fix->v_acc = TO_Q(vacc * 1000.0, 0);
    fix->s_acc = TO_Q(sacc * 1000.0, 0);
    fix->age = TO_Q(age, 30);
    return 1;
}

int main(void)
{
    imu_navkf_t f;
    imu_navkf_fix_t fix;
    double rate, x[9];
    char kind[2];
    int k;
    if (scanf("%lf", &rate) != 1) {
        return 2;
    }
    if (scanf("%1s", kind) != 1 || (kind[0] != 'b' && kind[0] != 'k') || !read_fix(&fix, 0)) {
        return 2;
    }
    fix.source = kind[0] == 'k' ? IMU_NAVKF_MARKER : IMU_NAVKF_GNSS;
    {
        imu_q16_t acc[3];
        imu_real_t mag[3];
        for (k = 0; k < 6; ++k) {
            if (scanf("%lf", &x[k]) != 1) {
                return 2;
            }
        }
        for (k = 0; k < 3; ++k) {
            acc[k] = TO_Q(x[k], 16);
            mag[k] = TO_Q(x[3 + k], 16);
        }
        if (imu_navkf_start(&f, TO_Q(rate, 16), acc, mag, &fix, NULL) != IMU_OK) {
            return 3;
        }
    }
    while (scanf("%1s", kind) == 1) {
        if (kind[0] == 'f' || kind[0] == 'm') {
            if (!read_fix(&fix, 1)) {
                return 2;
            }
            fix.source = kind[0] == 'm' ? IMU_NAVKF_MARKER : IMU_NAVKF_GNSS;
            (void)imu_navkf_fix(&f, &fix);
        } else if (kind[0] == 'p') {
            double pressure;
            if (scanf("%lf", &pressure) != 1) {
                return 2;
            }
            imu_navkf_baro(&f, TO_Q(pressure, 0));
        } else if (kind[0] == 's') {
            imu_rate_t gyr[3];
            imu_q16_t acc[3];
            imu_real_t mag[3];
            imu_angle_t lat, lon;
            imu_real_t height;
            for (k = 0; k < 9; ++k) {
                if (scanf("%lf", &x[k]) != 1) {
                    return 2;
                }
            }
            for (k = 0; k < 3; ++k) {
                gyr[k] = TO_Q(x[k], 24);
                acc[k] = TO_Q(x[3 + k], 16);
                mag[k] = TO_Q(x[6 + k], 16);
            }
            imu_navkf_step(&f, gyr, acc, mag);
            imu_navkf_position(&f, &lat, &lon, &height);
            printf("%.12f %.12f %.6f", FROM_Q(lat, 29) / DEG, FROM_Q(lon, 29) / DEG, FROM_Q(height, 0) / 1000.0);
            for (k = 0; k < 3; ++k) {
                printf(" %.9g", FROM_Q(f.nav.vel[k], 20));
            }
            for (k = 0; k < 4; ++k) {
                printf(" %.12g", FROM_Q(f.nav.q[k], 30));
            }
            for (k = 0; k < IMU_NAVKF_STATES; ++k) {
                imu_real_t mant;
                int32_t e;
                imu_navkf_variance(&f, k, &mant, &e);
                printf(" %.6g", sqrt((double)mant * ldexp(1.0, (int)e - VAR_Q)) * UNIT[k]);
            }
            printf("\n");
        } else {
            return 2;
        }
    }
    printf("rejected %u zero_velocity %u saturations %u\n", (unsigned)f.rejected, (unsigned)f.zero_velocity,
           (unsigned)f.nav.saturations);
    return 0;
}
