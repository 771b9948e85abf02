/*
 * The reference firmware on an injected clock and a loopback cable: the device under test
 * of the conformance suite (loaded with ctypes by sim_devices/board/c_firmware.py).
 * One casfw_sim is a fixed-size block the caller allocates; there is no heap.
 */
#include <string.h>

#include "../casfw.h"
#include "../casfw_loopback.h"

typedef struct {
    casfw_board board;
    casfw_loopback world;
    casfw_ns t;
} casfw_sim;

static casfw_ns sim_now(void *ctx) { return ((casfw_sim *)ctx)->t; }

static void sim_io(void *ctx, uint64_t first, uint32_t n, const double *dac, unsigned n_dac,
                   double *adc, unsigned n_adc) {
    (void)first;
    casfw_loopback_io(&((casfw_sim *)ctx)->world, n, dac, n_dac, adc, n_adc);
}

static void sim_start(void *ctx) { casfw_loopback_reset(&((casfw_sim *)ctx)->world); }

size_t casfw_sim_size(void) { return sizeof(casfw_sim); }
size_t casfw_config_size(void) { return sizeof(casfw_config); }

void casfw_sim_init(casfw_sim *s, const casfw_config *cfg, uint32_t delay, double gain) {
    casfw_hal hal = {s, sim_now, sim_io, sim_start};
    s->t = 0;
    casfw_loopback_init(&s->world, delay, gain);
    casfw_init(&s->board, cfg, &hal);
}

/* Service at board time t_ns, then receive the host bytes (golden conversation step). */
void casfw_sim_step(casfw_sim *s, uint64_t t_ns, const uint8_t *host, size_t n) {
    s->t = t_ns;
    casfw_service(&s->board);
    if (n) casfw_receive(&s->board, host, n);
}

/* Receive without a service pass (bytes arriving between two passes). */
void casfw_sim_receive(casfw_sim *s, const uint8_t *host, size_t n) {
    casfw_receive(&s->board, host, n);
}

size_t casfw_sim_take(casfw_sim *s, uint8_t *out, size_t cap) {
    return casfw_take_output(&s->board, out, cap);
}

void casfw_sim_default_config(casfw_config *cfg) { casfw_default_config(cfg); }

uint32_t casfw_sim_counter(const casfw_sim *s, int which) {
    switch (which) {
    case 0: return s->board.frames_ok;
    case 1: return s->board.frame_errors;
    case 2: return s->board.dac_underruns;
    case 3: return s->board.dac_level;
    case 5: return s->board.adc_clipped_samples;
    default: return (uint32_t)s->board.state;
    }
}

/*
 * The firmware with its HAL in the caller's hands (callbacks): the host simulation puts an
 * injected clock and any analog world (the acoustic tank) behind the same firmware.
 */
typedef casfw_ns (*casfw_ext_now)(void);
typedef void (*casfw_ext_io)(uint64_t first, uint32_t n, const double *dac, unsigned n_dac,
                             double *adc, unsigned n_adc);
typedef void (*casfw_ext_start)(void);

typedef struct {
    casfw_board board;
    casfw_ext_now now;
    casfw_ext_io io;
    casfw_ext_start start;
} casfw_ext;

static casfw_ns ext_now(void *ctx) { return ((casfw_ext *)ctx)->now(); }

static void ext_io(void *ctx, uint64_t first, uint32_t n, const double *dac, unsigned n_dac,
                   double *adc, unsigned n_adc) {
    ((casfw_ext *)ctx)->io(first, n, dac, n_dac, adc, n_adc);
}

static void ext_start(void *ctx) { ((casfw_ext *)ctx)->start(); }

size_t casfw_ext_size(void) { return sizeof(casfw_ext); }

void casfw_ext_init(casfw_ext *e, const casfw_config *cfg, casfw_ext_now now, casfw_ext_io io,
                    casfw_ext_start start) {
    casfw_hal hal = {e, ext_now, ext_io, ext_start};
    e->now = now;
    e->io = io;
    e->start = start;
    casfw_init(&e->board, cfg, &hal);
}

void casfw_ext_receive(casfw_ext *e, const uint8_t *data, size_t n) {
    casfw_receive(&e->board, data, n);
}
void casfw_ext_service(casfw_ext *e) { casfw_service(&e->board); }
size_t casfw_ext_take(casfw_ext *e, uint8_t *out, size_t cap) {
    return casfw_take_output(&e->board, out, cap);
}
void casfw_ext_link_lost(casfw_ext *e) { casfw_link_lost(&e->board); }
uint64_t casfw_ext_index_at(const casfw_ext *e, uint64_t t_ns) {
    return casfw_index_at(&e->board, t_ns);
}
uint32_t casfw_ext_counter(const casfw_ext *e, int which) {
    switch (which) {
    case 0: return e->board.dac_underruns;
    case 2: return e->board.adc_clipped_samples;
    default: return e->board.adc_overruns;
    }
}
