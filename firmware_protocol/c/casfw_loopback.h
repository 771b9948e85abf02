/* A loopback cable as the analog world of a host build: ADC channel k hears DAC channel k,
 * delay_samples late, times gain (the Python LoopbackWorld, operation for operation). */
#ifndef CASFW_LOOPBACK_H
#define CASFW_LOOPBACK_H

#include "casfw.h"

#ifndef CASFW_LOOPBACK_MAX_DELAY
#define CASFW_LOOPBACK_MAX_DELAY 4096u
#endif

typedef struct {
    uint32_t delay;
    double gain;
    double line[CASFW_LOOPBACK_MAX_DELAY * CASFW_MAX_CHANNELS];
    uint32_t pos;
} casfw_loopback;

void casfw_loopback_init(casfw_loopback *w, uint32_t delay, double gain);
void casfw_loopback_reset(casfw_loopback *w);
void casfw_loopback_io(casfw_loopback *w, uint32_t n, const double *dac, unsigned n_dac,
                       double *adc, unsigned n_adc);

#endif
