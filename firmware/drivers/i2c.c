/**
 * @file i2c.c
 * @brief Texts of the I2C transfer results (see i2c.h).
 */
#include "i2c.h"

const char *i2c_status_text(i2c_status_t status)
{
    switch (status) {
    case I2C_OK:
        return "OK";
    case I2C_ERR_NACK_ADDRESS:
        return "address not acknowledged";
    case I2C_ERR_NACK_DATA:
        return "data not acknowledged";
    case I2C_ERR_TIMEOUT:
        return "timeout";
    case I2C_ERR_BUS:
        return "bus error";
    case I2C_ERR_ARBITRATION:
        return "arbitration lost";
    }
    /* A value outside the enum (a board returning garbage) still gets a text. */
    return "unknown I2C status";
}
