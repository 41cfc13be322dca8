/**
 * @file i2c_stm32f4.c
 * @brief I2C1 master, polled (see i2c_stm32f4.h), after RM0090 rev 19 section 27.
 *
 * Set-up (section 27.3.3, "the following is the required sequence in master mode"):
 * CR2.FREQ = APB1 clock in MHz; CCR in fast mode with DUTY = 0, where Thigh = CCR * Tpclk1 and
 * Tlow = 2 * CCR * Tpclk1, so CCR = ceil(pclk1 / (3 * 400 kHz)) (42 MHz: 35, exactly 400 kHz;
 * at least 4, section 27.6.8); TRISE = 300 ns * FREQ + 1 (the fast-mode maximum rise time, as
 * the section 27.6.9 example computes 1000 ns / Tpclk1 + 1 for standard mode; 42 MHz: 13);
 * OAR1 bit 14 kept at 1 (section 27.6.3); CCR and TRISE are written while PE = 0; then PE = 1.
 *
 * Master transmitter (section 27.3.3, figure "transfer sequence diagram for master transmitter"):
 *   START; EV5: SB, cleared by reading SR1 then writing DR with the address;
 *   EV6: ADDR, cleared by reading SR1 then SR2;
 *   EV8_1 / EV8: TxE, write the next byte to DR;
 *   EV8_2: TxE and BTF after the last byte: STOP (or, in write_read, a repeated START).
 * Master receiver (same section, figure "... for master receiver", and "closing the
 * communication", method 2, the one for polling):
 *   1 byte:  at EV6 clear ACK, then clear ADDR and program STOP (with interrupts masked, so
 *            STOP is set before the byte ends), then read DR when RxNE;
 *   2 bytes: POS = 1 and ACK = 1 before the START; at EV6 clear ADDR, then clear ACK (masked:
 *            with POS the NACK applies to the second byte); wait BTF (both bytes in); STOP;
 *            read DR twice;
 *   N > 2:   ACK = 1; read bytes at RxNE until three are left; wait BTF (DataN-2 in DR,
 *            DataN-1 in the shift register, SCL stretched); clear ACK; read DataN-2; program
 *            STOP; read DataN-1; read DataN when RxNE (EV7_2).
 * While START or STOP is pending, CR1 is not written (section 27.6.1: "the software must not
 * perform any write access to I2C_CR1 before this bit is cleared by hardware").
 * Errors (section 27.3.4): AF (a NACK) -> STOP, AF cleared (rc_w0, written 0), the status says
 * whether the address (AF during EV6) or a data byte was refused; a refused data byte (the next
 * one may be waiting in DR), BERR, ARLO and timeouts also reset the peripheral
 * (RCC_APB1RSTR.I2C1RST, which releases the lines), clear the bus by hand and configure it
 * again, so the next transfer starts from a known state.
 */
#include "i2c_stm32f4.h"

#include "board_stm32f407.h"
#include "stm32f4.h"
#include "timers.h"

#define EVENT_TIMEOUT_US 1000u   /* one event: a byte takes 23 us at 400 kHz, 24 us at 381 kHz */
#define IDLE_TIMEOUT_US 1000u    /* a STOP to complete / BUSY to clear before a transfer */
#define SCL_RISE_TIMEOUT_US 1000u /* bus clear: SCL released but held low (clock stretching) */
#define BUS_CLEAR_HALF_PERIOD_US 5u /* SCL pulses by hand at 100 kHz (standard mode for any chip) */
#define BUS_CLEAR_PULSES 9u      /* UM10204 section 3.1.16 "bus clear": nine clock pulses */

#define SCL_BIT (1u << BOARD_I2C_SCL_PIN)
#define SDA_BIT (1u << BOARD_I2C_SDA_PIN)

/* --------------------------------------------------------------------------- bounded waits */

typedef struct {
    uint64_t deadline_us;
    uint32_t polls_left;
} deadline_t;

/* Each poll takes at least one CPU cycle, so `us` * cpu_mhz polls last at least `us`: the
 * backstop never ends a wait early, and still ends it where the microsecond clock stands still. */
static deadline_t deadline_in(const i2c_stm32f4_t *dev, uint32_t us)
{
    deadline_t d;
    d.deadline_us = timers_time_us() + us;
    d.polls_left = us * dev->cpu_mhz + 16u;
    return d;
}

static int expired(deadline_t *d)
{
    if (d->polls_left == 0u) {
        return 1;
    }
    --d->polls_left;
    return timers_time_us() > d->deadline_us; /* whole microseconds: more than `us` have passed */
}

void i2c_stm32f4_delay_us(const i2c_stm32f4_t *dev, uint32_t us)
{
    deadline_t d = deadline_in(dev, us);
    while (!expired(&d)) {
    }
}

void i2c_stm32f4_delay_ms(void *context, uint32_t ms)
{
    const i2c_stm32f4_t *dev = (const i2c_stm32f4_t *)context;
    while (ms > 0u) { /* in slices of at most 10 ms: the poll backstop (us * MHz) stays in 32 bits */
        const uint32_t slice = ms > 10u ? 10u : ms;
        i2c_stm32f4_delay_us(dev, slice * 1000u);
        ms -= slice;
    }
}

/* --------------------------------------------------------------------------- pins (RM0090 section 8) */

static void set_field2(volatile uint32_t *reg, uint32_t pin, uint32_t value)
{
    *reg = (*reg & ~(3u << (2u * pin))) | (value << (2u * pin));
}

/** Pin settings common to both modes: open-drain, medium speed, internal pull-up (a weak one,
 *  so a missing module reads as an idle bus; the GY-86's own pull-ups do the work). */
static void pins_common(void)
{
    gpio_t *const gpio = BOARD_I2C_GPIO;
    gpio->OTYPER |= SCL_BIT | SDA_BIT;
    set_field2(&gpio->OSPEEDR, BOARD_I2C_SCL_PIN, GPIO_SPEED_MEDIUM);
    set_field2(&gpio->OSPEEDR, BOARD_I2C_SDA_PIN, GPIO_SPEED_MEDIUM);
    set_field2(&gpio->PUPDR, BOARD_I2C_SCL_PIN, GPIO_PULL_UP);
    set_field2(&gpio->PUPDR, BOARD_I2C_SDA_PIN, GPIO_PULL_UP);
}

/** SCL and SDA as open-drain outputs driven by ODR, released (ODR = 1) first. */
static void pins_to_gpio(void)
{
    gpio_t *const gpio = BOARD_I2C_GPIO;
    gpio->BSRR = SCL_BIT | SDA_BIT;
    pins_common();
    set_field2(&gpio->MODER, BOARD_I2C_SCL_PIN, GPIO_MODE_OUTPUT);
    set_field2(&gpio->MODER, BOARD_I2C_SDA_PIN, GPIO_MODE_OUTPUT);
}

/** SCL and SDA to I2C1 (AF4 in AFRH), the alternate function selected before the mode. */
static void pins_to_i2c(void)
{
    gpio_t *const gpio = BOARD_I2C_GPIO;
    const uint32_t scl_shift = 4u * (BOARD_I2C_SCL_PIN - 8u), sda_shift = 4u * (BOARD_I2C_SDA_PIN - 8u);
    pins_common();
    gpio->AFR[1] = (gpio->AFR[1] & ~((0xFu << scl_shift) | (0xFu << sda_shift))) |
                   ((uint32_t)BOARD_I2C_AF << scl_shift) | ((uint32_t)BOARD_I2C_AF << sda_shift);
    set_field2(&gpio->MODER, BOARD_I2C_SCL_PIN, GPIO_MODE_AF);
    set_field2(&gpio->MODER, BOARD_I2C_SDA_PIN, GPIO_MODE_AF);
}

static uint32_t lines(void)
{
    return BOARD_I2C_GPIO->IDR & (SCL_BIT | SDA_BIT);
}

/** Release SCL (ODR = 1) and wait, bounded, until it reads high (a chip may stretch it). */
static int release_scl(const i2c_stm32f4_t *dev)
{
    deadline_t d;
    BOARD_I2C_GPIO->BSRR = SCL_BIT;
    d = deadline_in(dev, SCL_RISE_TIMEOUT_US);
    while (!(lines() & SCL_BIT)) {
        if (expired(&d)) {
            return 0;
        }
    }
    return 1;
}

/**
 * The bus by hand, pins as GPIO: while SDA is low (a slave stopped mid-byte keeps driving a 0)
 * pulse SCL, at most 9 times, then a STOP (SDA rises while SCL is high) so every chip starts
 * afresh. `always_stop`: send the STOP even when SDA was high (after an aborted transfer).
 */
static i2c_lines_t clear_bus(i2c_stm32f4_t *dev, int always_stop)
{
    gpio_t *const gpio = BOARD_I2C_GPIO;
    const uint32_t half = BUS_CLEAR_HALF_PERIOD_US;
    i2c_lines_t result = I2C_LINES_IDLE;
    unsigned pulses = 0;

    pins_to_gpio();
    i2c_stm32f4_delay_us(dev, half);
    if (!release_scl(dev)) {
        result = I2C_LINES_SCL_LOW;
    } else {
        if (!(lines() & SDA_BIT)) {
            ++dev->bus_clears;
            while (!(lines() & SDA_BIT) && pulses < BUS_CLEAR_PULSES) {
                gpio->BSRR = SCL_BIT << 16; /* SCL low */
                i2c_stm32f4_delay_us(dev, half);
                if (!release_scl(dev)) {
                    break;
                }
                i2c_stm32f4_delay_us(dev, half);
                ++pulses;
            }
            result = (lines() & SDA_BIT) ? I2C_LINES_FREED : I2C_LINES_SDA_LOW;
            if (!(lines() & SCL_BIT)) {
                result = I2C_LINES_SCL_LOW;
            }
        }
        if (result == I2C_LINES_FREED || (result == I2C_LINES_IDLE && always_stop)) {
            gpio->BSRR = SCL_BIT << 16; /* SCL low, then SDA low: no START while SCL is high */
            i2c_stm32f4_delay_us(dev, half);
            gpio->BSRR = SDA_BIT << 16;
            i2c_stm32f4_delay_us(dev, half);
            (void)release_scl(dev);
            i2c_stm32f4_delay_us(dev, half);
            gpio->BSRR = SDA_BIT; /* SDA rises while SCL is high: STOP */
            i2c_stm32f4_delay_us(dev, half);
        }
    }
    pins_to_i2c();
    return result;
}

/* --------------------------------------------------------------------------- the peripheral */

void i2c_stm32f4_timing(uint32_t pclk1_hz, uint32_t *freq, uint32_t *ccr, uint32_t *trise)
{
    const uint32_t mhz = pclk1_hz / 1000000u;
    uint32_t c = (pclk1_hz + 3u * BOARD_I2C_SPEED_HZ - 1u) / (3u * BOARD_I2C_SPEED_HZ);
    *freq = mhz < 2u ? 2u : (mhz > 42u ? 42u : mhz);
    if (c < 4u) {
        c = 4u;
    }
    *ccr = c > I2C_CCR_MASK ? I2C_CCR_MASK : c;
    *trise = (*freq * 300u) / 1000u + 1u;
}

/** Registers after a reset (PE = 0): timing, own address register, then PE = 1. */
static void configure(const i2c_stm32f4_t *dev)
{
    uint32_t freq, ccr, trise;
    i2c_stm32f4_timing(dev->pclk1_hz, &freq, &ccr, &trise);
    I2C1->CR1 = 0u;
    I2C1->CR2 = (I2C1->CR2 & ~0x1FFFu) | freq; /* FREQ; interrupts and DMA off (bits 15:13 reserved) */
    I2C1->OAR1 = I2C_OAR1_BIT14;
    I2C1->CCR = I2C_CCR_FS | ccr; /* fast mode, DUTY = 0 */
    I2C1->TRISE = trise;
    I2C1->CR1 = I2C_CR1_PE;
}

/** Reset I2C1 through RCC (releases the lines whatever state it was in), clear the bus, set up again. */
static void recover(i2c_stm32f4_t *dev)
{
    ++dev->recoveries;
    RCC->APB1RSTR |= RCC_APB1RSTR_I2C1RST;
    (void)RCC->APB1RSTR;
    RCC->APB1RSTR &= ~RCC_APB1RSTR_I2C1RST;
    (void)clear_bus(dev, 1);
    configure(dev);
}

i2c_lines_t i2c_stm32f4_init(i2c_stm32f4_t *dev, uint32_t pclk1_hz, uint32_t cpu_hz, i2c_bus_t *bus)
{
    dev->pclk1_hz = pclk1_hz;
    dev->cpu_mhz = cpu_hz / 1000000u > 0u ? cpu_hz / 1000000u : 1u;
    dev->transfers = dev->failures = dev->recoveries = dev->bus_clears = 0;
    RCC->AHB1ENR |= BOARD_I2C_GPIO_EN;
    RCC->APB1ENR |= RCC_APB1ENR_I2C1EN;
    (void)RCC->APB1ENR; /* the enables take effect before the first access (a read back) */
    RCC->APB1RSTR |= RCC_APB1RSTR_I2C1RST;
    (void)RCC->APB1RSTR;
    RCC->APB1RSTR &= ~RCC_APB1RSTR_I2C1RST;
    /* Look at the lines before the peripheral drives them: a slave reset (or stopped) in the
     * middle of a read may hold SDA low, and the peripheral would then never get a START out. */
    pins_to_gpio();
    i2c_stm32f4_delay_us(dev, BUS_CLEAR_HALF_PERIOD_US);
    if ((lines() & (SCL_BIT | SDA_BIT)) != (SCL_BIT | SDA_BIT)) {
        dev->start_lines = clear_bus(dev, 0);
    } else {
        dev->start_lines = I2C_LINES_IDLE;
        pins_to_i2c();
    }
    configure(dev);
    bus->write = i2c_stm32f4_write;
    bus->write_read = i2c_stm32f4_write_read;
    bus->delay_ms = i2c_stm32f4_delay_ms;
    bus->context = dev;
    return dev->start_lines;
}

/* --------------------------------------------------------------------------- transfer steps */

/** Wait until every bit of `flags` is set in SR1. An error flag ends the wait: AF is the
 *  address's NACK during EV6 (`address_phase`), a data byte's otherwise. */
static i2c_status_t wait_sr1(const i2c_stm32f4_t *dev, uint32_t flags, int address_phase)
{
    deadline_t d = deadline_in(dev, EVENT_TIMEOUT_US);
    for (;;) {
        const uint32_t sr1 = I2C1->SR1;
        if (sr1 & I2C_SR1_BERR) {
            return I2C_ERR_BUS;
        }
        if (sr1 & I2C_SR1_ARLO) {
            return I2C_ERR_ARBITRATION;
        }
        if (sr1 & I2C_SR1_AF) {
            return address_phase ? I2C_ERR_NACK_ADDRESS : I2C_ERR_NACK_DATA;
        }
        if ((sr1 & flags) == flags) {
            return I2C_OK;
        }
        if (expired(&d)) {
            return I2C_ERR_TIMEOUT;
        }
    }
}

/** Wait until the hardware has cleared CR1's STOP bit (the STOP went out). */
static int wait_stop_sent(const i2c_stm32f4_t *dev)
{
    deadline_t d = deadline_in(dev, IDLE_TIMEOUT_US);
    while (I2C1->CR1 & I2C_CR1_STOP) {
        if (expired(&d)) {
            return 0;
        }
    }
    return 1;
}

/** Before a transfer: no STOP pending, bus not busy (or recovered), POS and ACK cleared. */
static i2c_status_t begin(i2c_stm32f4_t *dev)
{
    deadline_t d;
    int attempt;
    ++dev->transfers;
    for (attempt = 0; attempt < 2; ++attempt) {
        if (wait_stop_sent(dev)) {
            d = deadline_in(dev, IDLE_TIMEOUT_US);
            while ((I2C1->SR2 & I2C_SR2_BUSY) && !expired(&d)) {
            }
            if (!(I2C1->SR2 & I2C_SR2_BUSY) && (I2C1->CR1 & I2C_CR1_PE)) {
                I2C1->CR1 &= ~(I2C_CR1_POS | I2C_CR1_ACK);
                return I2C_OK;
            }
        }
        recover(dev);
    }
    return I2C_ERR_TIMEOUT;
}

/** End of a transfer that failed with `status`: release the bus as the error requires. */
static i2c_status_t fail(i2c_stm32f4_t *dev, i2c_status_t status)
{
    ++dev->failures;
    if (status == I2C_ERR_NACK_ADDRESS || status == I2C_ERR_NACK_DATA) {
        /* Section 27.3.4, acknowledge failure: "if master: a Stop or repeated Start condition
         * must be generated by software". AF is rc_w0: written 0, the other flags written 1. */
        I2C1->CR1 |= I2C_CR1_STOP;
        I2C1->SR1 = I2C_SR1_ERROR_FLAGS & ~I2C_SR1_AF;
        if (wait_stop_sent(dev) && status == I2C_ERR_NACK_ADDRESS) {
            I2C1->CR1 &= ~(I2C_CR1_POS | I2C_CR1_ACK);
            return status;
        }
        /* A refused data byte: the next one may already sit in DR (written at TxE while the
         * refused one was on the bus), and nothing in RM0090 says a STOP empties DR; the
         * reset below does, so it cannot go out at the start of the next transfer. */
    }
    /* BERR (the master does not release the lines), ARLO (the interface went back to slave
     * mode), a timeout (state unknown), a refused data byte or a STOP that never went out:
     * start again from reset. */
    I2C1->SR1 = I2C_SR1_ERROR_FLAGS & ~(I2C_SR1_BERR | I2C_SR1_ARLO | I2C_SR1_AF);
    recover(dev);
    return status;
}

/** START (or repeated START), EV5, the address byte, EV6 (ADDR set, not cleared yet). */
static i2c_status_t start(const i2c_stm32f4_t *dev, uint8_t address, uint32_t read)
{
    i2c_status_t s;
    I2C1->CR1 |= I2C_CR1_START;
    s = wait_sr1(dev, I2C_SR1_SB, 0);
    if (s != I2C_OK) {
        return s;
    }
    I2C1->DR = ((uint32_t)address << 1) | read; /* after the SR1 read that saw SB: clears SB */
    return wait_sr1(dev, I2C_SR1_ADDR, 1);
}

/** EV6 ends: ADDR is cleared by reading SR1 then SR2. */
static void clear_addr(void)
{
    (void)I2C1->SR1;
    (void)I2C1->SR2;
}

/** STOP after a completed transfer, and wait until it went out. */
static i2c_status_t finish(i2c_stm32f4_t *dev)
{
    if (!wait_stop_sent(dev)) {
        return fail(dev, I2C_ERR_TIMEOUT);
    }
    I2C1->CR1 &= ~(I2C_CR1_POS | I2C_CR1_ACK);
    return I2C_OK;
}

/** Address + W and the bytes, up to EV8_2 (TxE and BTF: the last byte acknowledged, SCL held). */
static i2c_status_t send(const i2c_stm32f4_t *dev, uint8_t address, const uint8_t *data, size_t len)
{
    size_t i;
    i2c_status_t s = start(dev, address, 0u);
    if (s != I2C_OK) {
        return s;
    }
    clear_addr();
    for (i = 0; i < len; ++i) {
        s = wait_sr1(dev, I2C_SR1_TXE, 0); /* EV8_1, EV8 */
        if (s != I2C_OK) {
            return s;
        }
        I2C1->DR = data[i];
    }
    return len > 0u ? wait_sr1(dev, I2C_SR1_TXE | I2C_SR1_BTF, 0) : I2C_OK; /* EV8_2 */
}

/** Read `len` bytes after ADDR of a read address (EV6 pending); ends with the STOP programmed. */
static i2c_status_t receive(const i2c_stm32f4_t *dev, uint8_t *data, size_t len)
{
    uint32_t primask;
    size_t i;
    i2c_status_t s;
    if (len == 1u) {
        primask = irq_save();
        I2C1->CR1 &= ~I2C_CR1_ACK; /* in the ADDR event: NACK the only byte */
        clear_addr();
        I2C1->CR1 |= I2C_CR1_STOP;
        irq_restore(primask);
        s = wait_sr1(dev, I2C_SR1_RXNE, 0);
        if (s == I2C_OK) {
            data[0] = (uint8_t)I2C1->DR;
        }
        return s;
    }
    if (len == 2u) { /* POS and ACK were set before the START */
        primask = irq_save();
        clear_addr();
        I2C1->CR1 &= ~I2C_CR1_ACK; /* with POS: the second byte is NACKed */
        irq_restore(primask);
        s = wait_sr1(dev, I2C_SR1_BTF, 0); /* both bytes in: DR and the shift register */
        if (s != I2C_OK) {
            return s;
        }
        I2C1->CR1 |= I2C_CR1_STOP;
        data[0] = (uint8_t)I2C1->DR;
        s = wait_sr1(dev, I2C_SR1_RXNE, 0);
        if (s == I2C_OK) {
            data[1] = (uint8_t)I2C1->DR;
        }
        return s;
    }
    clear_addr(); /* ACK was set before the START */
    for (i = 0; i + 3u < len; ++i) {
        s = wait_sr1(dev, I2C_SR1_RXNE, 0); /* EV7 */
        if (s != I2C_OK) {
            return s;
        }
        data[i] = (uint8_t)I2C1->DR;
    }
    s = wait_sr1(dev, I2C_SR1_BTF, 0); /* EV7_2: DataN-2 in DR, DataN-1 in the shift register */
    if (s != I2C_OK) {
        return s;
    }
    primask = irq_save();
    I2C1->CR1 &= ~I2C_CR1_ACK;
    data[len - 3u] = (uint8_t)I2C1->DR; /* DataN-2: DataN is received next, NACKed */
    I2C1->CR1 |= I2C_CR1_STOP;
    irq_restore(primask);
    s = wait_sr1(dev, I2C_SR1_RXNE, 0);
    if (s != I2C_OK) {
        return s;
    }
    data[len - 2u] = (uint8_t)I2C1->DR; /* DataN-1 */
    s = wait_sr1(dev, I2C_SR1_RXNE, 0);
    if (s != I2C_OK) {
        return s;
    }
    data[len - 1u] = (uint8_t)I2C1->DR; /* DataN */
    return I2C_OK;
}

/* --------------------------------------------------------------------------- i2c_bus_t */

i2c_status_t i2c_stm32f4_write(void *context, uint8_t address, const uint8_t *data, size_t len)
{
    i2c_stm32f4_t *dev = (i2c_stm32f4_t *)context;
    i2c_status_t s = begin(dev);
    if (s != I2C_OK) {
        return fail(dev, s);
    }
    s = send(dev, address, data, len);
    if (s != I2C_OK) {
        return fail(dev, s);
    }
    I2C1->CR1 |= I2C_CR1_STOP; /* EV8_2 */
    return finish(dev);
}

i2c_status_t i2c_stm32f4_write_read(void *context, uint8_t address, const uint8_t *write_data, size_t write_len,
                                    uint8_t *read_data, size_t read_len)
{
    i2c_stm32f4_t *dev = (i2c_stm32f4_t *)context;
    i2c_status_t s;
    if (read_len == 0u) {
        return i2c_stm32f4_write(context, address, write_data, write_len);
    }
    s = begin(dev);
    if (s == I2C_OK && write_len > 0u) {
        s = send(dev, address, write_data, write_len); /* ends at EV8_2: a repeated START follows */
    }
    if (s == I2C_OK) {
        if (read_len == 2u) {
            I2C1->CR1 |= I2C_CR1_POS | I2C_CR1_ACK;
        } else if (read_len > 2u) {
            I2C1->CR1 |= I2C_CR1_ACK;
        }
        s = start(dev, address, 1u);
    }
    if (s == I2C_OK) {
        s = receive(dev, read_data, read_len);
    }
    if (s != I2C_OK) {
        return fail(dev, s);
    }
    return finish(dev);
}
