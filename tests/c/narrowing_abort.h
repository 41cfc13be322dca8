/* The test drivers' report of a narrowing that does not fit int32 (imu_arith.h's checked
 * mode, -DIMU_CHECK_NARROWING): say where, and abort. Included once, by the driver. */
#ifndef NARROWING_ABORT_H
#define NARROWING_ABORT_H

#ifdef IMU_CHECK_NARROWING
#include <stdio.h>
#include <stdlib.h>

void imu_narrowing_failed(const char *file, int line, const char *what, int64_t value)
{
    fprintf(stderr, "%s:%d: %s does not fit int32: %lld\n", file, line, what, (long long)value);
    abort();
}
#endif

#endif /* NARROWING_ABORT_H */
