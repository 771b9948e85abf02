/*
 * The reference firmware on an MPS2 AN386 (Cortex-M4) as QEMU emulates it.
 *
 * Byte link: UART0 (CMSDK APB UART at 0x40004000), which QEMU connects to a host pty with
 * `-serial pty`. Board time: SysTick on the 25 MHz system clock, extended to 64 bits by its
 * wrap interrupt. Sample I/O: QEMU's MPS2 has no DAC or ADC, so the analog path is the
 * loopback cable of casfw_loopback.c run on the MCU (the nearest real thing; a real board
 * puts its converters' DMA behind the same casfw_hal.sample_io).
 */
#include <stdint.h>

#include "../casfw.h"
#include "../casfw_loopback.h"

#define UART0 0x40004000u
#define UART_DATA (*(volatile uint32_t *)(UART0 + 0x00u))
#define UART_STATE (*(volatile uint32_t *)(UART0 + 0x04u))
#define UART_CTRL (*(volatile uint32_t *)(UART0 + 0x08u))
#define UART_BAUDDIV (*(volatile uint32_t *)(UART0 + 0x10u))
#define STATE_TX_FULL 0x1u
#define STATE_RX_FULL 0x2u

#define SYST_CSR (*(volatile uint32_t *)0xE000E010u)
#define SYST_RVR (*(volatile uint32_t *)0xE000E014u)
#define SYST_CVR (*(volatile uint32_t *)0xE000E018u)
#define SYSCLK_HZ 25000000u
#define NS_PER_TICK 40u

static volatile uint32_t systick_wraps;
static casfw_board board;
static casfw_loopback world;

void systick_handler(void) { systick_wraps++; }

#define ICSR (*(volatile uint32_t *)0xE000ED04u)
#define ICSR_PENDSTSET (1u << 26)

static casfw_ns mcu_now(void *ctx) {
    (void)ctx;
    uint32_t wraps, count, pending;
    do {
        wraps = systick_wraps;
        count = SYST_CVR;
        pending = ICSR & ICSR_PENDSTSET;
    } while (wraps != systick_wraps);
    /* Wrapped but its interrupt not yet taken: a count read after the reload is high. */
    if (pending && count > 0x800000u) wraps++;
    uint64_t ticks = ((uint64_t)wraps << 24) + (0xFFFFFFu - count);
    return ticks * NS_PER_TICK;
}

static void mcu_io(void *ctx, uint64_t first, uint32_t n, const double *dac, unsigned n_dac,
                   double *adc, unsigned n_adc) {
    (void)ctx;
    (void)first;
    casfw_loopback_io(&world, n, dac, n_dac, adc, n_adc);
}

static void mcu_start(void *ctx) {
    (void)ctx;
    casfw_loopback_reset(&world);
}

int main(void) {
    UART_BAUDDIV = 16u;
    UART_CTRL = 0x3u; /* TX and RX enabled */
    SYST_RVR = 0xFFFFFFu;
    SYST_CVR = 0u;
    SYST_CSR = 0x7u; /* processor clock, wrap interrupt, enabled */

    casfw_config cfg;
    casfw_default_config(&cfg);
    /* What QEMU's emulated UART carries both ways (about 64 kB/s measured): 2 x int16 at
     * 16 kS/s fills it, 48 kS/s overruns it. */
    static const uint32_t rates[] = {16000u, 8000u};
    cfg.n_rates = 2;
    for (unsigned i = 0; i < 2u; i++) cfg.sample_rates_hz[i] = rates[i];
    cfg.formats = 0x1; /* INT16 */
    cfg.dac_buffer_samples = 4096u;
    cfg.adc_buffer_samples = 4096u;
    cfg.board_serial = 0x4D500386u;
    casfw_hal hal = {0, mcu_now, mcu_io, mcu_start};
    casfw_loopback_init(&world, 0u, 1.0);
    casfw_init(&board, &cfg, &hal);

    static uint8_t in[512];
    static uint8_t out[256];
    uint32_t out_len = 0, out_pos = 0;
    for (;;) {
        uint32_t n = 0;
        while (n < sizeof in && (UART_STATE & STATE_RX_FULL)) in[n++] = (uint8_t)UART_DATA;
        if (n) casfw_receive(&board, in, n);
        casfw_service(&board);
        for (;;) {
            if (out_pos == out_len) {
                out_len = (uint32_t)casfw_take_output(&board, out, sizeof out);
                out_pos = 0;
                if (!out_len) break;
            }
            if (UART_STATE & STATE_TX_FULL) break;
            UART_DATA = out[out_pos++];
        }
    }
}
