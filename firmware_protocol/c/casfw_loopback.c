#include <string.h>

#include "casfw_loopback.h"

void casfw_loopback_init(casfw_loopback *w, uint32_t delay, double gain) {
    w->delay = delay > CASFW_LOOPBACK_MAX_DELAY ? CASFW_LOOPBACK_MAX_DELAY : delay;
    w->gain = gain;
    casfw_loopback_reset(w);
}

void casfw_loopback_reset(casfw_loopback *w) {
    memset(w->line, 0, sizeof w->line);
    w->pos = 0;
}

void casfw_loopback_io(casfw_loopback *w, uint32_t n, const double *dac, unsigned n_dac,
                       double *adc, unsigned n_adc) {
    unsigned k = n_dac < n_adc ? n_dac : n_adc;
    for (uint32_t i = 0; i < n; i++) {
        const double *in = dac + (size_t)i * n_dac;
        double *out = adc + (size_t)i * n_adc;
        for (unsigned c = 0; c < n_adc; c++) out[c] = 0.0;
        if (w->delay == 0) {
            for (unsigned c = 0; c < k; c++) out[c] = w->gain != 1.0 ? in[c] * w->gain : in[c];
            continue;
        }
        double *slot = w->line + (size_t)w->pos * CASFW_MAX_CHANNELS;
        for (unsigned c = 0; c < k; c++) out[c] = w->gain != 1.0 ? slot[c] * w->gain : slot[c];
        for (unsigned c = 0; c < n_dac && c < CASFW_MAX_CHANNELS; c++) slot[c] = in[c];
        w->pos = (w->pos + 1u) % w->delay;
    }
}
