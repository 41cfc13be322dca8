/**
 * @file board_qemu.c
 * @brief QEMU's netduinoplus2 machine (an STM32F405): the board application on the ARM
 *        core, with the host's simulator as its sensors.
 *
 * QEMU models the STM32F405's USART1-6, TIM2-5 and the core's SysTick, but not RCC,
 * GPIO, I2C, DMA or the DWT (they read as zero and ignore writes), so this board never
 * waits on those:
 * - USART1, the host link (QEMU's first -serial): the reference board's ring-buffered
 *   driver (boards/stm32f4/uart.h). QEMU's transmission is synchronous, so the ring
 *   empties as it is written; while the host does not read, QEMU itself waits.
 * - USART2, the sensor feed (QEMU's second -serial; boards/emulated/feed.h): every byte
 *   the board sends asks the feeder for one more sample frame; received bytes go by
 *   interrupt into a ring. The board keeps FEED_CREDIT requests outstanding while it
 *   streams, so the feeder's latency is hidden and no byte ever arrives unasked (QEMU
 *   drops bytes that arrive while the USART is off, e.g. during a reset).
 * - TIM5 counts microseconds and is also the cycle counter (there is no DWT):
 *   STATUS.cycle_hz is 1000000. Samples are due at exact multiples of the period on that
 *   clock (boards/emulated/schedule.h: a late board catches up from the sensor's FIFO);
 *   TIM2 only wakes the core (at 1 kHz, or at the sample rate above it), because QEMU
 *   7.2's TIM2 restarts each period late and runs about 8 % slow. The timers' clock
 *   differs between QEMU versions (1 GHz in 7.2, 48 MHz later), so it is measured at
 *   start-up against SysTick, which QEMU clocks at the CPU's 168 MHz.
 * Start-up options come from the semihosting command line (-semihosting-config
 * enable=on,arg=imulink-qemu,arg=--fast,...): `--fast` (a sample whenever the feed has
 * one, instead of the tick) and those of boards/emulated/options.h. Without semihosting
 * the request faults, the fault handler answers "no command line", the defaults apply.
 * ENTER_BOOTLOADER is not supported. QEMU ignores baud rates.
 */
#include "app.h"
#include "board.h"
#include "feed.h"
#include "identification.h"
#include "link.h"
#include "options.h"
#include "schedule.h"
#include "stm32f4.h"
#include "text.h"
#include "timers.h"
#include "uart.h"

#define SYSTICK_HZ 168000000u       /* netduinoplus2: the CPU clock, SysTick's processor clock */
#define APB2_CLOCK_HZ 84000000u     /* USART1's bus clock on a real F405 at 168 MHz (QEMU ignores BRR) */
#define APB1_CLOCK_HZ 42000000u     /* USART2's */
#define LINK_BAUD 921600u
#define FEED_REQUEST 0x53u          /* 'S': one byte asks the feeder for one more sample */
#define FEED_CREDIT 4u              /* requests outstanding: 4 of the largest frame (an end LOG) fit the ring */
#define FEED_TIMEOUT_US 50000u      /* a tick's sample later than this is a failed read (it comes next tick) */
#define PRIORITY_LINK 1u            /* received bytes must not wait behind the tick */
#define PRIORITY_FEED 1u
#define PRIORITY_TIMERS 2u

static uart_t feed_uart;
static feed_t feed;
static uint32_t timer_clock_hz;    /* TIM2-5's clock, measured */
static uint32_t feed_outstanding;  /* samples asked for and not yet decoded */
static int fast;                   /* --fast: no tick, a sample whenever the feed has one */
static int streaming;              /* the sample clock runs */
static schedule_t schedule;        /* real time: when samples are due */

/* A sample decoded from the feed and not yet handed to the application. */
static struct {
    feed_event_t event; /* FEED_MORE: none waiting */
    feed_sample_t sample;
} next_sample;
static feed_sample_t last_sample;  /* the sample handed to the application and what came with it */

void usart2_irq_handler(void);
APP_IDENTIFICATION("qemu-stm32f405", "STM32F405", 0x413u, 1024u);

void tim2_irq_handler(void);
void tim5_irq_handler(void);
void hard_fault_handler(void);
void hard_fault_report(uint32_t *frame);

void usart2_irq_handler(void)
{
    uart_irq(&feed_uart);
}

void tim2_irq_handler(void)
{
    timers_tim2_irq();
}

void tim5_irq_handler(void)
{
    timers_tim5_irq();
}

/* --------------------------------------------------------------------------- semihosting */

#define SEMIHOSTING_SYS_WRITE0 0x04
#define SEMIHOSTING_SYS_GET_CMDLINE 0x15
#define SEMIHOSTING_SYS_EXIT 0x18
#define SEMIHOSTING_EXIT_ERROR 0x20024u /* ADP_Stopped_InternalError: QEMU exits with status 1 */
#define BKPT_SEMIHOSTING 0xBEABu        /* the Thumb encoding of BKPT 0xAB */

static int semihosting(int operation, void *argument)
{
    register int r0 __asm__("r0") = operation;
    register void *r1 __asm__("r1") = argument;
    __asm__ volatile("bkpt 0xab" : "+r"(r0) : "r"(r1) : "memory");
    return r0;
}

/* A BKPT without a debugger or semihosting escalates to HardFault: answer -1 ("failed") and
 * go on after it; any other fault resets the chip. */
__attribute__((naked)) void hard_fault_handler(void)
{
    __asm__ volatile("tst lr, #4\n\t"
                     "ite eq\n\t"
                     "mrseq r0, msp\n\t"
                     "mrsne r0, psp\n\t"
                     "b hard_fault_report\n\t");
}

void hard_fault_report(uint32_t *frame)
{
    const uint16_t *pc = (const uint16_t *)frame[6];
    if (*pc == BKPT_SEMIHOSTING) {
        frame[0] = 0xFFFFFFFFu; /* r0 = -1 */
        frame[6] += 2u;         /* the instruction after the BKPT */
        return;
    }
    system_reset();
}

static void stop_with_error(const char *what)
{
    char line[160];
    text_t t;
    text_start(&t, line, sizeof line);
    text_add(&t, "imulink-qemu: ");
    text_add(&t, what);
    text_add(&t, "\n");
    (void)semihosting(SEMIHOSTING_SYS_WRITE0, line);
    (void)semihosting(SEMIHOSTING_SYS_EXIT, (void *)SEMIHOSTING_EXIT_ERROR);
    for (;;) {
    }
}

/** The options on the semihosting command line (the first word is the program's name). */
static void read_options(app_config_t *config)
{
    static char line[256];
    struct {
        char *buffer;
        int length;
    } request = {line, (int)sizeof line - 1};
    char *words[16];
    int count = 0, i;
    char *p = line;
    if (semihosting(SEMIHOSTING_SYS_GET_CMDLINE, &request) != 0) {
        return; /* no semihosting: the defaults */
    }
    line[request.length] = '\0';
    while (*p != '\0' && count < (int)(sizeof words / sizeof words[0])) {
        while (*p == ' ') {
            *p++ = '\0';
        }
        if (*p != '\0') {
            words[count++] = p;
        }
        while (*p != '\0' && *p != ' ') {
            ++p;
        }
    }
    for (i = 1; i < count; ++i) {
        const char *error = "";
        int applied;
        if (text_equal(words[i], "--fast")) {
            fast = 1;
            continue;
        }
        applied = options_apply(config, words[i], i + 1 < count ? words[i + 1] : 0, &error);
        if (applied == 0) {
            stop_with_error("unknown option on the semihosting command line");
        } else if (applied < 0) {
            stop_with_error(error);
        }
        ++i;
    }
}

/* --------------------------------------------------------------------------- clocks */

/** TIM2-5's clock: TIM5's count over 2^20 SysTick cycles (6 ms), rounded to 1 MHz. */
static uint32_t measure_timer_clock(void)
{
    const uint32_t window = 1u << 20;
    uint32_t start_tim, elapsed_tim, start_tick;
    uint64_t hz;
    SYSTICK->LOAD = 0x00FFFFFFu;
    SYSTICK->VAL = 0;
    SYSTICK->CTRL = 5u; /* enabled, processor clock, no interrupt */
    TIM5->PSC = 0;
    TIM5->ARR = 0xFFFFFFFFu;
    TIM5->EGR = TIM_EGR_UG;
    TIM5->CR1 = TIM_CR1_CEN;
    start_tick = SYSTICK->VAL;
    start_tim = TIM5->CNT;
    while (((start_tick - SYSTICK->VAL) & 0x00FFFFFFu) < window) {
    }
    elapsed_tim = TIM5->CNT - start_tim;
    TIM5->CR1 = 0;
    SYSTICK->CTRL = 0;
    hz = (uint64_t)elapsed_tim * SYSTICK_HZ / window;
    return (uint32_t)((hz + 500000u) / 1000000u * 1000000u);
}

/* --------------------------------------------------------------------------- the sensor feed */

/** Ask for samples until FEED_CREDIT are outstanding. */
static void feed_request(void)
{
    while (feed_outstanding < FEED_CREDIT) {
        uart_poll_put(USART2, FEED_REQUEST);
        ++feed_outstanding;
    }
}

/** Decode received feed bytes until a sample (or the end) is waiting in next_sample. */
static int feed_ready(void)
{
    uint8_t byte;
    while (next_sample.event == FEED_MORE && uart_read(&feed_uart, &byte, 1) == 1) {
        next_sample.event = feed_push(&feed, byte, &next_sample.sample);
        if (next_sample.event != FEED_MORE && feed_outstanding > 0) {
            --feed_outstanding;
        }
    }
    return next_sample.event != FEED_MORE;
}

/* --------------------------------------------------------------------------- board interface */

uint64_t board_time_us(void)
{
    return timers_time_us();
}

uint32_t board_cycles(void)
{
    return (uint32_t)timers_time_us();
}

uint32_t board_cycle_hz(void)
{
    return 1000000u;
}

#define WAKE_RATE_MHZ 1000000u /* 1 kHz */

void board_sample_clock_start(uint32_t rate_mhz)
{
    streaming = 1;
    schedule_start(&schedule, timers_time_us(), rate_mhz);
    feed_request();
    if (!fast) {
        timers_tick_start(timer_clock_hz, rate_mhz > WAKE_RATE_MHZ ? rate_mhz : WAKE_RATE_MHZ, PRIORITY_TIMERS);
    }
}

void board_sample_clock_stop(void)
{
    streaming = 0;
    timers_tick_stop();
}

uint32_t board_sample_ticks(void)
{
    if (fast) {
        return (uint32_t)(streaming && feed_ready());
    }
    (void)timers_tick_take(); /* the wake-ups; the samples due follow from the clock */
    return streaming ? schedule_ticks(&schedule, timers_time_us()) : 0;
}

board_sensors_result_t board_sensors_init(const char **message)
{
    *message = fast ? "sensor feed on USART2: an emulated GY-86, a sample whenever the feeder sends one"
                    : "sensor feed on USART2: an emulated GY-86";
    return BOARD_SENSORS_OK;
}

board_sensors_result_t board_sensors_read(imu_raw_sample_t *raw, int16_t *temperature, const char **message)
{
    const uint64_t deadline = timers_time_us() + FEED_TIMEOUT_US;
    feed_event_t event;
    feed_request();
    while (!feed_ready()) {
        if (timers_time_us() > deadline) {
            /* The sample may still come: it is then the next read's, so none is lost. */
            *message = "sensor feed on USART2: no sample within 50 ms";
            return BOARD_SENSORS_FAILED;
        }
        board_idle();
    }
    event = next_sample.event;
    next_sample.event = FEED_MORE;
    feed_request();
    if (event == FEED_ENDED) {
        *message = feed.end_text;
        return BOARD_SENSORS_ENDED;
    }
    last_sample = next_sample.sample;
    *raw = last_sample.raw;
    *temperature = last_sample.temperature;
    return BOARD_SENSORS_OK;
}

int board_baro_read(uint64_t now_us, board_baro_t *out)
{
    (void)now_us; /* the feed's conversions came with the sample */
    return feed_baro_take(&last_sample.baro, out);
}

int board_gnss_read(uint64_t now_us, imu_proto_gnss_t *fix)
{
    (void)now_us; /* the feed's fix came with the sample */
    return feed_gnss_take(&last_sample.gnss, fix);
}

void board_idle(void)
{
    const uint32_t primask = irq_save();
    if (!link_has_byte() && !uart_has_byte(&feed_uart) && !timers_tick_pending()) {
        wait_for_interrupt();
    }
    irq_restore(primask);
}

void board_restart(void)
{
    system_reset();
}

const char *board_news(uint8_t *level)
{
    (void)level;
    return 0; /* the feed's receiver has no state of its own to report */
}

const char *board_start_up_problem(void)
{
    return 0;
}

int board_has_bootloader(void)
{
    return 0;
}

void board_enter_bootloader(void)
{
}

int main(void)
{
    static app_t app;
    app_config_t config;
    options_defaults(&config, app_identification.board);
    read_options(&config);
    timer_clock_hz = measure_timer_clock();
    timers_clock_init(timer_clock_hz, PRIORITY_TIMERS);
    link_init(APB2_CLOCK_HZ, LINK_BAUD, PRIORITY_LINK);
    uart_init(&feed_uart, USART2, IRQ_USART2, APB1_CLOCK_HZ, LINK_BAUD, PRIORITY_FEED);
    feed_init(&feed);
    next_sample.event = FEED_MORE;
    app_init(&app, &config);
    for (;;) {
        const app_result_t result = app_poll(&app);
        if (result == APP_RESTART) {
            board_restart();
        } else if (result == APP_IDLE) {
            board_idle();
        }
    }
}
