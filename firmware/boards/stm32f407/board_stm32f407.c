/**
 * @file board_stm32f407.c
 * @brief The reference board: an STM32F407 with a GY-86 (MPU6050 + HMC5883L) on I2C1 and the
 *        host on USART1 at 921600 baud. Register level, no vendor library (boards/stm32f4).
 *
 * - Clocks: clock_stm32f407.c (8 MHz HSE -> PLL -> 168 MHz; fallbacks HSI -> PLL, HSI alone);
 *   every clock below is the one actually in use, and what went wrong is the start-up WARNING.
 * - Host link: USART1 on PA9/PA10 through the ring-buffered driver of boards/stm32f4/uart.h.
 * - GNSS receiver (optional): USART2 on PA2/PA3, the same driver under drivers/gnss.h
 *   (gnss_usart2.c); its fixes go to the application each sample.
 * - Sensors: gy86_init / gy86_read (drivers/) over i2c_stm32f4.c on I2C1 (PB8/PB9), polled.
 *   The MPU6050's INT pin is not connected: TIM2 times the samples.
 * - Time: TIM5 counts microseconds (64 bits with its overflow interrupt), TIM2 raises the
 *   sample tick, both from the APB1 timer clock (84 MHz); the DWT cycle counter counts CPU
 *   cycles for STATUS.filter_cycles (board_cycle_hz() = SYSCLK). Nothing waits on the DWT.
 * - ENTER_BOOTLOADER: a request word in .noinit RAM and a reset; the next start jumps to the ST
 *   system-memory bootloader (AN2606) before touching the clocks.
 */
#include "app.h"
#include "board.h"
#include "board_stm32f407.h"
#include "clock_stm32f407.h"
#include "gnss_usart2.h"
#include "gy86.h"
#include "i2c_stm32f4.h"
#include "identification.h"
#include "link.h"
#include "ms5611.h"
#include "stm32f4.h"
#include "text.h"
#include "timers.h"

#define BOOTLOADER_REQUEST 0x5B007B00u /* and its complement in the second word */

static clocks_t clocks;
static i2c_stm32f4_t i2c_dev;
static i2c_bus_t i2c_bus;
static gy86_t gy86;
static int sensors_ready;              /* gy86_init succeeded: reads may go to the bus */
static ms5611_t baro;                  /* the GY-86's barometer on the same bus */
static int baro_ready;                 /* ms5611_init succeeded: the sample loop polls it */
static char init_failure[SENSOR_STATUS_TEXT_SIZE + 24];
static char read_failure[SENSOR_STATUS_TEXT_SIZE];
static char start_up_problem[IMU_PROTO_LOG_SIZE];

/* Kept across a reset (linker script: .noinit is neither loaded nor cleared). */
static volatile uint32_t bootloader_request[2] __attribute__((section(".noinit")));

APP_IDENTIFICATION("stm32f407-gy86", "STM32F407", 0x413u, 1024u);

void tim2_irq_handler(void);
void tim5_irq_handler(void);

void tim2_irq_handler(void)
{
    timers_tim2_irq();
}

void tim5_irq_handler(void)
{
    timers_tim5_irq();
}

/* --------------------------------------------------------------------------- start-up */

/**
 * First thing after a reset, with the reset clocks (the HSI) the bootloader expects: when the
 * previous run asked for it, forget the request, map the system memory at 0 (SYSCFG_MEMRMP,
 * RM0090 section 9.2.1, so the bootloader finds its vector table where VTOR = 0 points) and
 * start it from its own vector table at 0x1FFF0000 (AN2606: STM32F40xxx/41xxx).
 */
static void start_bootloader_if_requested(void)
{
    const volatile uint32_t *const vectors = (const volatile uint32_t *)BOARD_SYSTEM_MEMORY;
    if (bootloader_request[0] != BOOTLOADER_REQUEST || bootloader_request[1] != ~BOOTLOADER_REQUEST) {
        return;
    }
    bootloader_request[0] = 0;
    bootloader_request[1] = 0;
    RCC->APB2ENR |= RCC_APB2ENR_SYSCFGEN;
    (void)RCC->APB2ENR;
    SYSCFG->MEMRMP = (SYSCFG->MEMRMP & ~SYSCFG_MEMRMP_MEM_MODE_MASK) | SYSCFG_MEMRMP_MEM_MODE_SYSTEM_FLASH;
    jump_to_image(vectors[0], vectors[1]);
}

static void set_field(volatile uint32_t *reg, uint32_t width, uint32_t position, uint32_t value)
{
    const uint32_t mask = ((1u << width) - 1u) << (width * position);
    *reg = (*reg & ~mask) | (value << (width * position));
}

/** A USART's TX pin (push-pull) and RX pin (pull-up: an unconnected RX reads idle, not
 *  noise) on alternate function `af`; the alternate function is selected before the mode
 *  (RM0090 section 8.3). AFR[0] holds pins 0-7, AFR[1] pins 8-15. */
static void uart_pins_init(gpio_t *gpio, uint32_t tx, uint32_t rx, uint32_t af)
{
    gpio->OTYPER &= ~(1u << tx);
    set_field(&gpio->OSPEEDR, 2u, tx, GPIO_SPEED_MEDIUM);
    set_field(&gpio->OSPEEDR, 2u, rx, GPIO_SPEED_MEDIUM);
    set_field(&gpio->PUPDR, 2u, tx, GPIO_PULL_NONE);
    set_field(&gpio->PUPDR, 2u, rx, GPIO_PULL_UP);
    set_field(&gpio->AFR[tx / 8u], 4u, tx % 8u, af);
    set_field(&gpio->AFR[rx / 8u], 4u, rx % 8u, af);
    set_field(&gpio->MODER, 2u, tx, GPIO_MODE_AF);
    set_field(&gpio->MODER, 2u, rx, GPIO_MODE_AF);
}

/** DWT CYCCNT (ARMv7-M architecture reference manual, C1.8): TRCENA in DEMCR, then CYCCNTENA. */
static void cycle_counter_init(void)
{
    DEMCR |= DEMCR_TRCENA;
    DWT->CYCCNT = 0;
    DWT->CTRL |= DWT_CTRL_CYCCNTENA;
}

/** The start-up WARNING: the clock problem, the baud rate it leads to, the I2C lines. */
static void describe_start_up(i2c_lines_t lines)
{
    text_t t;
    const uint32_t brr = (clocks.pclk2_hz + BOARD_LINK_BAUD / 2u) / BOARD_LINK_BAUD; /* as uart.c rounds */
    const uint32_t baud = brr > 0u ? clocks.pclk2_hz / brr : 0u;
    const uint32_t off = baud > BOARD_LINK_BAUD ? baud - BOARD_LINK_BAUD : BOARD_LINK_BAUD - baud;
    text_start(&t, start_up_problem, sizeof start_up_problem);
    if (clocks.problem != 0) {
        text_add(&t, clocks.problem);
    }
    if (off * 100u > BOARD_LINK_BAUD) { /* more than 1 % off */
        text_add(&t, text_length(start_up_problem) > 0 ? "; " : "");
        text_add(&t, "USART1 at ");
        text_add_uint(&t, baud);
        text_add(&t, " baud");
    }
    if (lines != I2C_LINES_IDLE) {
        text_add(&t, text_length(start_up_problem) > 0 ? "; " : "");
        text_add(&t, lines == I2C_LINES_FREED   ? "I2C1: SDA was held low at start-up, freed by SCL pulses"
                     : lines == I2C_LINES_SDA_LOW ? "I2C1: SDA held low, not freed by 9 SCL pulses"
                                                  : "I2C1: SCL held low at start-up");
    }
    (void)text_end(&t);
}

/* --------------------------------------------------------------------------- board interface */

uint64_t board_time_us(void)
{
    return timers_time_us();
}

uint32_t board_cycles(void)
{
    return DWT->CYCCNT;
}

uint32_t board_cycle_hz(void)
{
    return clocks.sysclk_hz;
}

void board_sample_clock_start(uint32_t rate_mhz)
{
    timers_tick_start(clocks.apb1_timer_hz, rate_mhz, BOARD_PRIORITY_TIMERS);
}

void board_sample_clock_stop(void)
{
    timers_tick_stop();
}

uint32_t board_sample_ticks(void)
{
    return timers_tick_take();
}

board_sensors_result_t board_sensors_init(const char **message)
{
    static const uint16_t gyro_dps[4] = {250, 500, 1000, 2000};
    static const uint8_t acc_g[4] = {2, 4, 8, 16};
    const gy86_config_t *config = &gy86_default_config;
    char status_text[SENSOR_STATUS_TEXT_SIZE];
    const sensor_status_t s = gy86_init(&gy86, &i2c_bus, config);
    text_t t;
    text_start(&t, init_failure, sizeof init_failure);
    sensors_ready = !sensor_failed(&s);
    if (!sensors_ready) {
        text_add(&t, "GY-86 not ready: ");
        text_add(&t, sensor_status_text(&s, status_text, sizeof status_text));
        *message = text_end(&t);
        return BOARD_SENSORS_FAILED;
    }
    text_add(&t, "GY-86: MPU6050 + HMC5883L ready, +-");
    text_add_uint(&t, gyro_dps[(unsigned)config->mpu.gyro_range & 3u]);
    text_add(&t, " deg/s, +-");
    text_add_uint(&t, acc_g[(unsigned)config->mpu.acc_range & 3u]);
    text_add(&t, " g, ");
    text_add_uint(&t, hmc5883l_lsb_per_gauss(config->mag.gain));
    text_add(&t, " LSB/gauss");
    {
        /* The barometer is optional: the attitude filters run without it. OSR 4096: the
         * finest pressure (0.012 mbar rms, DS); a D1 + D2 cycle takes 18 ms. */
        const sensor_status_t b = ms5611_init(&baro, &i2c_bus, MS5611_ADDRESS, MS5611_OSR_4096);
        baro_ready = !sensor_failed(&b);
        text_add(&t, baro_ready ? "; MS5611 ready" : "; no MS5611: ");
        if (!baro_ready) {
            text_add(&t, sensor_status_text(&b, status_text, sizeof status_text));
        }
    }
    *message = text_end(&t);
    return BOARD_SENSORS_OK;
}

int board_baro_read(uint64_t now_us, board_baro_t *out)
{
    ms5611_reading_t r;
    sensor_status_t s;
    int ready = 0;
    if (!baro_ready) {
        return 0;
    }
    /* a failed step restarts the driver's cycle at the next call: no measurement this time */
    s = ms5611_poll(&baro, (uint32_t)now_us, &r, &ready);
    if (sensor_failed(&s) || !ready) {
        return 0;
    }
    out->d1 = r.d1;
    out->d2 = r.d2;
    out->pressure_pa = r.pressure_pa;
    out->temperature_cdeg = r.temperature_cdeg;
    return 1;
}

board_sensors_result_t board_sensors_read(imu_raw_sample_t *raw, int16_t *temperature, const char **message)
{
    sensor_status_t s;
    if (!sensors_ready) {
        *message = init_failure; /* the application sets the sensors up again once a second */
        return BOARD_SENSORS_FAILED;
    }
    s = gy86_read(&gy86, raw, temperature);
    if (sensor_failed(&s)) {
        *message = sensor_status_text(&s, read_failure, sizeof read_failure);
        return BOARD_SENSORS_FAILED;
    }
    return BOARD_SENSORS_OK; /* a magnetometer overflow is delivered: the core flags the clipped axis */
}

int board_gnss_read(uint64_t now_us, imu_proto_gnss_t *fix)
{
    return gnss_usart2_poll((uint32_t)(now_us / 1000u), fix); /* ms, wrapping as the driver expects */
}

const char *board_news(uint8_t *level)
{
    return gnss_usart2_news(level);
}

const char *board_start_up_problem(void)
{
    return start_up_problem[0] != '\0' ? start_up_problem : 0;
}

void board_idle(void)
{
    const uint32_t primask = irq_save(); /* no interrupt between the check and the WFI is lost */
    if (!link_has_byte() && !timers_tick_pending()) {
        wait_for_interrupt(); /* a pending interrupt wakes the core even while PRIMASK masks it */
    }
    irq_restore(primask);
}

void board_restart(void)
{
    system_reset();
}

int board_has_bootloader(void)
{
    return 1;
}

void board_enter_bootloader(void)
{
    (void)irq_save();
    bootloader_request[0] = BOOTLOADER_REQUEST;
    bootloader_request[1] = ~BOOTLOADER_REQUEST;
    system_reset(); /* its DSB makes the two stores reach the RAM first */
}

int main(void)
{
    static app_t app;
    app_config_t config;
    i2c_lines_t lines;

    start_bootloader_if_requested();
    clocks_init(&clocks);
    cycle_counter_init();

    RCC->AHB1ENR |= BOARD_LINK_GPIO_EN | BOARD_I2C_GPIO_EN | BOARD_GNSS_GPIO_EN;
    RCC->APB1ENR |= RCC_APB1ENR_TIM2EN | RCC_APB1ENR_TIM5EN | RCC_APB1ENR_USART2EN;
    RCC->APB2ENR |= RCC_APB2ENR_USART1EN;
    (void)RCC->APB2ENR; /* the enables take effect before the first access (a read back) */

    timers_clock_init(clocks.apb1_timer_hz, BOARD_PRIORITY_TIMERS);
    uart_pins_init(BOARD_LINK_GPIO, BOARD_LINK_TX_PIN, BOARD_LINK_RX_PIN, BOARD_LINK_AF);
    link_init(clocks.pclk2_hz, BOARD_LINK_BAUD, BOARD_PRIORITY_LINK);
    uart_pins_init(BOARD_GNSS_GPIO, BOARD_GNSS_TX_PIN, BOARD_GNSS_RX_PIN, BOARD_GNSS_AF);
    gnss_usart2_init(clocks.pclk1_hz, BOARD_PRIORITY_GNSS, (uint32_t)(board_time_us() / 1000u));
    lines = i2c_stm32f4_init(&i2c_dev, clocks.pclk1_hz, clocks.hclk_hz, &i2c_bus);
    describe_start_up(lines);

    config.board_name = app_identification.board;
    config.sample_rate = (imu_real_t)100 << 16;
    config.initial_filter = IMU_FILTER_ESKF;
    gy86_sensor_settings(&gy86_default_config, &config.sensor);

    app_init(&app, &config);
    for (;;) {
        const app_result_t result = app_poll(&app);
        if (result == APP_RESTART) {
            board_restart();
        } else if (result == APP_BOOTLOADER) {
            board_enter_bootloader();
        } else if (result == APP_IDLE) {
            board_idle();
        }
    }
}
