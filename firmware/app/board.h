/**
 * @file board.h
 * @brief The board interface: everything the application needs from the hardware.
 *
 * The application (app.c) is written once; each board (firmware/boards/<name>/)
 * implements these functions for its hardware: the reference STM32F407 + GY-86,
 * QEMU's netduinoplus2, and the native host process. Nothing else in app/ knows
 * which board it runs on. See docs/firmware.md for how to port to another board.
 *
 * Threading: the application calls these from its main loop only; interrupt
 * handlers live inside the board and talk to the application through the
 * non-blocking calls below (a received byte, a sample tick).
 */
#ifndef BOARD_H
#define BOARD_H

#include <stddef.h>
#include <stdint.h>

#include "imu_proto.h"
#include "imu_sensor.h"

/* --------------------------------------------------------------------------- host link (a UART) */

/** @brief Bytes received from the host since the last call, at most `cap`; never waits. */
size_t board_link_read(uint8_t *buf, size_t cap);

/** @brief Bytes board_link_write() accepts now without waiting (free transmit buffer). */
size_t board_link_space(void);

/** @brief Queue bytes for the host. Waits for room when the buffer is full (never drops). */
void board_link_write(const uint8_t *data, size_t len);

/** @brief Wait until every queued byte has left (before a reset or a jump to the bootloader). */
void board_link_flush(void);

/* --------------------------------------------------------------------------- clocks */

/** @brief Microseconds since start-up (does not wrap in practice: 64 bits). */
uint64_t board_time_us(void);

/** @brief A free-running counter for measuring work, in board_cycle_hz() units (wraps at 2^32). */
uint32_t board_cycles(void);

/** @brief Frequency of board_cycles(), Hz (the CPU clock where the board has a cycle counter). */
uint32_t board_cycle_hz(void);

/* --------------------------------------------------------------------------- sample clock */

/** @brief Start (or restart) the sample tick at `rate_mhz` (mHz: 100 Hz = 100000; never 0). */
void board_sample_clock_start(uint32_t rate_mhz);

/** @brief Stop the sample tick. */
void board_sample_clock_stop(void);

/** @brief Sample ticks since the last call (0: no sample is due; more than 1: samples were missed). */
uint32_t board_sample_ticks(void);

/* --------------------------------------------------------------------------- sensors */

/** Result of a sensor call. */
typedef enum {
    BOARD_SENSORS_OK = 0,
    BOARD_SENSORS_FAILED = 1, /**< no sample this time (the message says why); later calls may succeed */
    BOARD_SENSORS_ENDED = 2,  /**< an emulated sensor feed has no more samples (the message says why) */
} board_sensors_result_t;

/**
 * @brief Find and configure the sensors (again, after a failure).
 * @param message set to a one-line description: what was found, or why it failed.
 */
board_sensors_result_t board_sensors_init(const char **message);

/**
 * @brief Read one sample: register counts in the core's sensor axes (imu_sensor.h) and the
 *        MPU6050 temperature register.
 * @param message set to why there is no sample, when the result is not BOARD_SENSORS_OK.
 */
board_sensors_result_t board_sensors_read(imu_raw_sample_t *raw, int16_t *temperature, const char **message);

/** One barometer measurement (the GY-86's MS5611): its raw conversions and their
 *  compensation with the chip's PROM. */
typedef struct {
    uint32_t d1;              /**< raw pressure conversion, 24 bits */
    uint32_t d2;              /**< raw temperature conversion, 24 bits */
    int32_t pressure_pa;      /**< Pa */
    int32_t temperature_cdeg; /**< 0.01 degC */
} board_baro_t;

/**
 * @brief The barometer's measurement completed since the last call, if any; never waits
 *        (the app calls it after every sample read, which also keeps the MS5611's
 *        conversions going on a board that drives one).
 * @param now_us board time, us
 * @return 1 with *out filled, 0 when nothing new (or the board has no barometer).
 */
int board_baro_read(uint64_t now_us, board_baro_t *out);

/**
 * @brief The GNSS receiver's fix that arrived since the last call, if any; never waits.
 * @param fix filled but for timestamp_us and index (the application's)
 * @return 1 with *fix filled, 0 when nothing new (or the board has no receiver).
 */
int board_gnss_read(uint64_t now_us, imu_proto_gnss_t *fix);

/* --------------------------------------------------------------------------- system */

/** @brief What went wrong while the board started (a crystal that did not start, say), for a
 *         WARNING after HELLO; NULL when nothing did. */
const char *board_start_up_problem(void);

/**
 * @brief A change on the board since the last call that the host should hear of (a GNSS
 *        receiver found, configured, lost, never answering, or sending damaged frames).
 *        Called after each live sample; NULL when there is none.
 * @param level the LOG level of the line (IMU_PROTO_LOG_LEVEL_*)
 */
const char *board_news(uint8_t *level);

/** @brief Sleep until something may have happened (a byte, a tick, an interrupt). May return early. */
void board_idle(void);

/** @brief Restart the firmware (after RESET's ACK has been flushed). A board may return, and the
 *         application then starts afresh in the same process (the native board does). */
void board_restart(void);

/** @brief 1 when the board can reboot into a serial bootloader (ENTER_BOOTLOADER is ACKed). */
int board_has_bootloader(void);

/** @brief Reboot into the serial bootloader (after ENTER_BOOTLOADER's ACK has been flushed). */
void board_enter_bootloader(void);

#endif /* BOARD_H */
