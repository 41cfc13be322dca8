/* Drives the nav filter as the board runs it (imu_navfilter.c through imu_filter.h) for
 * tests/test_nav_board.py, under the sanitizers (the fixed build with every narrowing
 * checked): a still board whose every sample is followed by a GNSS frame, a marker and a
 * pressure made of extreme values from a fixed pseudo-random sequence (every field at
 * INT32/UINT32 limits, zero, or ordinary), and the NAV_STATE of each sample (fixed build).
 * Prints "samples N gnss_used N markers_used N saturations N mode M" at the end; any
 * undefined behaviour or narrowing aborts. Built with -DIMU_FIXED -DIMU_CHECK_NARROWING
 * and with -DIMU_FLOAT. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "imu_filter.h"
#include "imu_wire.h"

#include "narrowing_abort.h"

static uint64_t state = 0x9E3779B97F4A7C15u;

static uint32_t next(void)
{
    state ^= state << 13;
    state ^= state >> 7;
    state ^= state << 17;
    return (uint32_t)(state >> 16);
}

/** An extreme, zero or ordinary int32. */
static int32_t pick(int32_t ordinary)
{
    static const int32_t extremes[] = {INT32_MIN, INT32_MAX, 0, -1, 1, 850000000, -850000000, 1800000000};
    const uint32_t r = next() % 12u;
    return r < 8u ? extremes[r] : ordinary + (int32_t)(next() % 2001u) - 1000;
}

int main(int argc, char **argv)
{
    const int samples = argc > 1 ? atoi(argv[1]) : 3000;
    imu_filter_t f;
    imu_navfilter_settings_t settings = imu_navfilter_default_settings;
    int gnss_used = 0, markers_used = 0, k, i;
    if (imu_filter_init(&f, IMU_FILTER_NAV) != IMU_OK) {
        return 2;
    }
    settings.lever_arm_y = IMU_QCONST(10.0, 16); /* the largest: every product of the arm at its limit */
    settings.gnss_latency = IMU_QCONST(1.0, 16);
    if (imu_filter_set_settings(&f, &settings) != IMU_OK) {
        return 3;
    }
    for (k = 0; k < samples; ++k) {
        /* a still board (gy86-default counts: 4096 per g, a 20 uT field), now and then a jolt */
        imu_raw_sample_t raw = {{0, 0, 0}, {0, 0, 4096}, {0, 200, -400}};
        imu_proto_gnss_t g;
        imu_navfilter_gnss_t fix;
        imu_navfilter_t *nav = imu_filter_nav(&f);
        imu_output_t out;
        if (k % 97 == 50) {
            for (i = 0; i < 3; ++i) {
                raw.gyr[i] = (int16_t)(next() % 2u ? 32767 : -32768);
                raw.acc[i] = (int16_t)(next() % 2u ? 32767 : -32768);
            }
        }
        imu_filter_update_raw(&f, &raw);
        g.time_ms = next();
        g.fix_type = (uint8_t)(next() % 2u ? 3 : next() % 6u);
        g.fix_ok = (uint8_t)(next() % 4u != 0u);
        g.num_sv = (uint8_t)next();
        g.has_velocity = (uint8_t)(next() % 2u);
        g.lat_1e7deg = pick(473769000);
        g.lon_1e7deg = pick(85417000);
        g.height_mm = pick(450000);
        g.h_acc_mm = (uint32_t)pick(2500);
        g.v_acc_mm = (uint32_t)pick(5000);
        g.s_acc_mm_s = (uint32_t)pick(100);
        for (i = 0; i < 3; ++i) {
            g.vel_ned_mm_s[i] = pick(0);
        }
        imu_navfilter_baro(nav, pick(96000));
        imu_wire_gnss_fix(&g, &fix);
        gnss_used += imu_navfilter_gnss(nav, &fix);
        if (k % 13 == 0) {
            markers_used += imu_navfilter_marker(nav, pick(473769000), pick(85417000), pick(450000),
                                                 (uint32_t)pick(100), (uint32_t)pick(100));
        }
        imu_filter_get(&f, &out);
#ifdef IMU_FIXED
        {
            imu_proto_nav_state_t s; /* the NAV_STATE the board would send */
            imu_wire_nav_state(nav, (uint32_t)k, &s);
        }
#endif
    }
    {
        const imu_navkf_t *kf = imu_navfilter_state(imu_filter_nav(&f));
        printf("samples %d gnss_used %d markers_used %d saturations %lu mode %d\n", samples, gnss_used, markers_used,
               (unsigned long)imu_filter_saturations(&f), kf == 0 ? 0 : (kf->anchored ? 2 : 1));
    }
    return 0;
}
