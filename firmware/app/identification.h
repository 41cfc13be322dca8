/**
 * @file identification.h
 * @brief The identification block of a flashable image: which board and chip it was built
 *        for, the firmware version and the protocol schema it speaks.
 *
 * Each ARM board defines one `app_identification` (APP_IDENTIFICATION below); the linker
 * script keeps it right after the vector table (section .imulink_id). A flashing tool finds
 * it in any image format by its magic (host/imulink/io/firmware_image.py reads it), refuses an
 * image built for another board or chip, and after flashing checks that the board's HELLO
 * reports the same version and schema hash. HELLO's board name is the block's.
 *
 * Layout (little-endian, 56 bytes, no padding on any target):
 *   0  magic "IMULNKID"        24 ... (board continues)    44 firmware major, minor, patch (u8 x 3)
 *   8  layout (u16): 1         28 chip (char[16])          47 protocol version (u8)
 *  10  size (u16): 56                                      48 schema hash (u32)
 *  12  board (char[16])                                    52 device id (u16), 54 flash size, KiB (u16)
 * Text fields are NUL-padded; the device id is the one the chip's system bootloader
 * reports (GET_ID, AN3155): 0x413 for the STM32F405/407.
 */
#ifndef IDENTIFICATION_H
#define IDENTIFICATION_H

#include <stddef.h>
#include <stdint.h>

#include "app.h"

typedef struct {
    char magic[8];
    uint16_t layout;
    uint16_t size;
    char board[16];
    char chip[16];
    uint8_t firmware_version[3];
    uint8_t protocol_version;
    uint32_t schema_hash;
    uint16_t device_id;
    uint16_t flash_kib;
} app_identification_t;

typedef char app_identification_is_56_bytes[(sizeof(app_identification_t) == 56 &&
                                              offsetof(app_identification_t, schema_hash) == 48) ? 1 : -1];

/** The image's block (defined by the board with APP_IDENTIFICATION). */
extern const app_identification_t app_identification;

/** Define the block: board name (HELLO's, at most 15 characters), chip name, bootloader device id, flash KiB. */
#define APP_IDENTIFICATION(board_name, chip_name, device, flash)                                               \
    __attribute__((section(".imulink_id"), used)) const app_identification_t app_identification = {          \
        "IMULNKID", 1u, (uint16_t)sizeof(app_identification_t), board_name, chip_name,                      \
        {APP_VERSION_MAJOR, APP_VERSION_MINOR, APP_VERSION_PATCH}, IMU_PROTO_VERSION, IMU_PROTO_SCHEMA_HASH, \
        device, flash}

#endif /* IDENTIFICATION_H */
