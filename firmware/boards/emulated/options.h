/**
 * @file options.h
 * @brief Start-up options of the emulated boards (native command line, QEMU semihosting
 *        command line): sensor profile, sample rate, initial filter.
 *
 * `--profile NAME`  the sensor ranges the fed counts are in: gy86-default (MPU6050 at
 *                   +-2000 deg/s and +-8 g, HMC5883L at 1090 LSB/gauss) or gy86-broad
 *                   (the same at +-16 g), as in host/imulink/core/counts.py
 * `--rate HZ`       the default sample_rate of every filter, a decimal number of Hz
 * `--filter NAME`   eecf, kf1d or eskf: the filter active after start-up
 */
#ifndef OPTIONS_H
#define OPTIONS_H

#include "app.h"

/** @brief The defaults: gy86-default, 100 Hz, EECF, and `board_name`. */
void options_defaults(app_config_t *config, const char *board_name);

/**
 * @brief Apply one option if it is one of the above.
 * @param name the option with its dashes ("--rate"); value: its argument (may be NULL).
 * @param error set to a one-line reason when the value is bad.
 * @return 1 applied, 0 not one of these options, -1 a bad or missing value.
 */
int options_apply(app_config_t *config, const char *name, const char *value, const char **error);

/** @brief Usage lines of these options, for --help. */
extern const char options_usage[];

#endif /* OPTIONS_H */
