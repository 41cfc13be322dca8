/**
 * @file gnss.h
 * @brief A GNSS receiver on a UART: finds it, configures it, and delivers its fixes.
 *
 * For u-blox M8/M9 receivers (the NEO-M8N modules sold for GY-86 boards), with NMEA 0183
 * as the fallback for receivers that do not take UBX configuration. Follows the u-blox 8
 * / M8 protocol specification (UBX-13003221): CFG-PRT, CFG-MSG, CFG-RATE, ACK-ACK and
 * ACK-NAK, NAV-PVT (ubx.h).
 *
 * The driver never waits and never touches hardware: the board feeds it the receiver's
 * bytes (gnss_push) and the time (gnss_poll, at least every 10 ms or so), sends the bytes
 * it asks for (gnss_take_tx), and keeps its UART at gnss_baud(). Start-up:
 *
 * 1. Searching: the UART listens at each candidate baud in turn (the configured one, then
 *    the receivers' usual ones, 9600 first: a u-blox receiver starts at 9600 with NMEA on)
 *    for GNSS_LISTEN_MS; a valid UBX frame or NMEA sentence means a receiver is there.
 * 2. Configuring: CFG-PRT moves its UART1 to the configured baud with UBX and NMEA in and
 *    UBX out (not acknowledged on the old baud reliably: the driver follows after
 *    GNSS_BAUD_SETTLE_MS and checks the next answer), CFG-MSG turns NAV-PVT on at every
 *    navigation epoch, CFG-RATE sets the epoch period. Each waits for its ACK-ACK up to
 *    GNSS_ACK_TIMEOUT_MS, GNSS_ATTEMPTS times. An ACK-NAK of CFG-RATE (a rate the receiver
 *    cannot do) is counted and the receiver keeps its own rate; no answer to CFG-MSG at the
 *    new baud nor at the found one means a receiver that does not speak UBX: the driver
 *    goes back to the found baud and runs on its NMEA GGA and RMC.
 * 3. Running: each NAV-PVT (or NMEA GGA, with the RMC of the same second) is a fix. A
 *    receiver silent for GNSS_LOST_MS (unplugged, rebooted to its default baud) is
 *    searched for again.
 *
 * No dynamic memory, integer only, bounded time per call.
 */
#ifndef GNSS_H
#define GNSS_H

#include <stddef.h>
#include <stdint.h>

#include "nmea.h"
#include "ubx.h"

/** How long the UART listens at one candidate baud: a receiver sends at least once a second. */
#define GNSS_LISTEN_MS 1500u
/** Time for CFG-PRT to leave at the old baud before the UART changes to the new one. */
#define GNSS_BAUD_SETTLE_MS 100u
/** Wait for an ACK-ACK or ACK-NAK. */
#define GNSS_ACK_TIMEOUT_MS 500u
/** Tries of each CFG message before the driver gives up on it. */
#define GNSS_ATTEMPTS 3u
/** Silence after which a running receiver counts as lost. */
#define GNSS_LOST_MS 3000u
/** Largest frame the driver sends (CFG-PRT: 20 bytes of payload). */
#define GNSS_TX_CAP 32u

/** Settings. */
typedef struct {
    uint32_t baud;         /**< the UART's baud once configured, e.g. 115200 (NAV-PVT at 10 Hz needs 9600 or more) */
    uint16_t meas_rate_ms; /**< navigation epoch period, ms: 100 (10 Hz) to 1000 (1 Hz) */
} gnss_config_t;

/** 115200 baud, 10 Hz. */
extern const gnss_config_t gnss_default_config;

/** Where the driver is. */
typedef enum {
    GNSS_SEARCHING = 0,   /**< listening for a receiver, baud by baud */
    GNSS_CONFIGURING = 1, /**< sending CFG messages */
    GNSS_RUNNING_UBX = 2, /**< fixes from NAV-PVT */
    GNSS_RUNNING_NMEA = 3 /**< fixes from NMEA GGA + RMC */
} gnss_state_t;

/** A fix, in the units of ubx.h. */
typedef struct {
    uint32_t time_ms;          /**< NAV-PVT: GPS time of week; NMEA: UTC time of day */
    uint8_t fix_type;          /**< ubx_fix_type_t; NMEA: UBX_FIX_3D for a GGA with a fix, else UBX_FIX_NONE */
    uint8_t fix_ok;            /**< within the receiver's accuracy masks (NAV-PVT gnssFixOK; NMEA: GGA quality > 0) */
    uint8_t num_sv;            /**< satellites used */
    uint8_t has_velocity;      /**< 1: vel_ned_mm_s is valid (NAV-PVT); NMEA has speed and course only */
    int32_t lat_1e7deg;        /**< latitude, 1e-7 deg */
    int32_t lon_1e7deg;        /**< longitude, 1e-7 deg */
    int32_t height_mm;         /**< height above the WGS-84 ellipsoid, mm */
    uint32_t h_acc_mm;         /**< horizontal accuracy estimate, mm (0: not given, NMEA) */
    uint32_t v_acc_mm;         /**< vertical accuracy estimate, mm (0: not given, NMEA) */
    int32_t vel_ned_mm_s[3];   /**< velocity north, east, down, mm/s */
    uint32_t s_acc_mm_s;       /**< speed accuracy estimate, mm/s (0: not given) */
    uint32_t speed_mm_s;       /**< ground speed, mm/s */
    uint32_t course_1e5deg;    /**< course over ground, 1e-5 deg (NMEA RMC; NAV-PVT: 0) */
    uint16_t hdop_cent;        /**< NMEA GGA's horizontal DOP, 0.01 (NAV-PVT: its position DOP) */
} gnss_fix_t;

/** Counters, for the board's status messages. */
typedef struct {
    uint32_t searches;     /**< candidate bauds listened at */
    uint32_t found;        /**< times a receiver was found */
    uint32_t lost;         /**< times a running receiver went silent */
    uint32_t timeouts;     /**< CFG messages without an answer in time */
    uint32_t naks;         /**< CFG messages the receiver refused */
    uint32_t fixes;        /**< fixes delivered */
} gnss_counters_t;

/** The driver. Members are private but `counters`, `ubx` and `nmea` (their own counters). */
typedef struct {
    gnss_config_t config;
    ubx_parser_t ubx;
    nmea_parser_t nmea;
    gnss_counters_t counters;
    uint8_t state;          /**< gnss_state_t */
    uint8_t step;           /**< configuring: which CFG message; searching: which candidate baud */
    uint8_t attempts;       /**< of the current CFG message */
    uint8_t waiting;        /**< configuring: 1 while an answer is awaited */
    uint32_t baud;          /**< the UART's baud now */
    uint32_t found_baud;    /**< where the receiver was found */
    uint32_t started_ms;    /**< when the current listen, wait or settle began */
    uint32_t last_heard_ms; /**< the last valid frame or sentence */
    uint32_t now_ms;        /**< the last time the board gave */
    uint8_t tx[GNSS_TX_CAP];
    uint16_t tx_len;
    nmea_rmc_t rmc;         /**< the last RMC, for the next GGA of the same second */
    uint8_t rmc_valid;
    gnss_fix_t fix;
} gnss_t;

/** @brief Start searching at `now_ms`. `config` is copied. */
void gnss_init(gnss_t *g, const gnss_config_t *config, uint32_t now_ms);

/**
 * @brief One byte from the receiver.
 * @return 1 when it completed a fix (gnss_fix() has it until the next call), else 0.
 */
int gnss_push(gnss_t *g, uint8_t byte);

/** @brief The passing of time (ms, any origin, wraps at 2^32): timeouts, the next step. */
void gnss_poll(gnss_t *g, uint32_t now_ms);

/** @brief Bytes to send to the receiver now (at gnss_baud()); at most `cap`; they leave the driver. */
size_t gnss_take_tx(gnss_t *g, uint8_t *out, size_t cap);

/** @brief The baud the board's UART must have now. */
uint32_t gnss_baud(const gnss_t *g);

/** @brief How many bauds one search tries (the configured one and the usual ones). */
uint8_t gnss_candidates(const gnss_t *g);

/** @brief gnss_state_t. */
gnss_state_t gnss_state(const gnss_t *g);

/** @brief The last fix (valid after gnss_push returned 1). */
const gnss_fix_t *gnss_fix(const gnss_t *g);

#endif /* GNSS_H */
