/* Cortex-M4 start-up: vector table, .data/.bss set-up, FPU on, then main(). */
#include <stdint.h>

extern uint32_t _data_load, _data_start, _data_end, _bss_start, _bss_end, _stack_top;
extern int main(void);
void reset_handler(void);
void systick_handler(void);

static void default_handler(void) {
    for (;;) {
    }
}

#define HANDLER(f) ((uintptr_t)(f))
__attribute__((section(".vectors"), used)) static const uintptr_t vectors[16] = {
    (uintptr_t)&_stack_top,   HANDLER(reset_handler),   HANDLER(default_handler),
    HANDLER(default_handler), HANDLER(default_handler), HANDLER(default_handler),
    HANDLER(default_handler), 0, 0, 0, 0, HANDLER(default_handler),
    HANDLER(default_handler), 0, HANDLER(default_handler), HANDLER(systick_handler),
};

void reset_handler(void) {
    uint32_t *src = &_data_load, *dst = &_data_start;
    while (dst < &_data_end) *dst++ = *src++;
    for (dst = &_bss_start; dst < &_bss_end;) *dst++ = 0;
    *(volatile uint32_t *)0xE000ED88u |= 0xFu << 20; /* CPACR: CP10, CP11 full access */
    __asm__ volatile("dsb\n isb");
    main();
    for (;;) {
    }
}
