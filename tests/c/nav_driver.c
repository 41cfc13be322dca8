/* Drives imu_nav.c for tests/test_nav.py: reads from stdin
 *   rate_hz lat0_deg lon0_deg height0_m qw qx qy qz vel_e vel_n vel_u
 * then one sample per line until EOF,
 *   gyr_x gyr_y gyr_z (rad/s) acc_x acc_y acc_z (m/s^2)
 * and prints first "gravity G" (normal gravity at the origin, m/s^2), after each sample
 * "east_m north_m up_m vel_e vel_n vel_u qw qx qy qz", then "saturations N". Built twice,
 * with -DIMU_FIXED (and -DIMU_CHECK_NARROWING: every int64 -> int32 narrowing checked) and
 * -DIMU_FLOAT. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "imu_nav.h"

#include "narrowing_abort.h"

#ifdef IMU_FIXED
#define TO_Q(x, q) ((int32_t)llround((x) * ldexp(1.0, (q))))
#define FROM_Q(x, q) ((double)(x) * ldexp(1.0, -(q)))
#else
#define TO_Q(x, q) (x)
#define FROM_Q(x, q) (x)
#endif

int main(void)
{
    const double deg = 3.14159265358979323846 / 180.0;
    double rate, lat, lon, height, q[4], vel[3], g[3], a[3];
    imu_nav_origin_t origin;
    imu_q30_t q0[4];
    imu_real_t v0[3];
    imu_nav_t nav;
    int k;
    if (scanf("%lf %lf %lf %lf %lf %lf %lf %lf %lf %lf %lf", &rate, &lat, &lon, &height, &q[0], &q[1], &q[2], &q[3],
              &vel[0], &vel[1], &vel[2]) != 11) {
        return 2;
    }
    origin.lat = TO_Q(lat * deg, 29);
    origin.lon = TO_Q(lon * deg, 29);
    origin.height = TO_Q(height * 1000.0, 0);
    for (k = 0; k < 4; ++k) {
        q0[k] = TO_Q(q[k], 30);
    }
    for (k = 0; k < 3; ++k) {
        v0[k] = TO_Q(vel[k], 20);
    }
    if (imu_nav_start(&nav, &origin, TO_Q(rate, 16), q0, v0) != IMU_OK) {
        return 3;
    }
    printf("gravity %.17g\n", FROM_Q(nav.gravity, 24));
    while (scanf("%lf %lf %lf %lf %lf %lf", &g[0], &g[1], &g[2], &a[0], &a[1], &a[2]) == 6) {
        imu_rate_t gyr[3];
        imu_q16_t acc[3];
        for (k = 0; k < 3; ++k) {
            gyr[k] = TO_Q(g[k], 24);
            acc[k] = TO_Q(a[k], 16);
        }
        imu_nav_propagate(&nav, gyr, acc);
        printf("%.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g %.17g\n", FROM_Q(nav.pos[0], 0) / 1000.0,
               FROM_Q(nav.pos[1], 0) / 1000.0, FROM_Q(nav.pos[2], 0) / 1000.0, FROM_Q(nav.vel[0], 20),
               FROM_Q(nav.vel[1], 20), FROM_Q(nav.vel[2], 20), FROM_Q(nav.q[0], 30), FROM_Q(nav.q[1], 30),
               FROM_Q(nav.q[2], 30), FROM_Q(nav.q[3], 30));
    }
    printf("saturations %u\n", (unsigned)nav.saturations);
    return 0;
}
