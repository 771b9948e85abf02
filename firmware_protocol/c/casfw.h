/*
 * casfw: C99 reference firmware of the CAS HIL board protocol 2.0 (../SPEC.md).
 *
 * The device role only: framing (COBS, CRC-32 with the schema seed), message checks, the
 * session state machine of SPEC section 2, and the behaviour and timing of SPEC section 5
 * (refusals, sample clock, DAC data by index, credits, watchdog, latched alarms).
 *
 * No heap, no I/O: a casfw_board is one fixed-size object the caller places anywhere.
 * Bytes from the host go in with casfw_receive(), the periodic service pass is
 * casfw_service(), and bytes for the host come out of casfw_take_output(). Time and the
 * sample converters come through the small HAL below (casfw_hal).
 */
#ifndef CASFW_H
#define CASFW_H

#include <stddef.h>
#include <stdint.h>

#define CASFW_PROTOCOL_MAJOR 2u
#define CASFW_PROTOCOL_MINOR 0u
/* CRC-32 of the canonical schema text of SPEC section 1.2 (checked by the test suite). */
#define CASFW_SCHEMA_HASH 0x547429dbu

#define CASFW_MAX_FRAME_LEN 8192u /* decoded bytes: header + payload + CRC */
#define CASFW_MAX_ENCODED (CASFW_MAX_FRAME_LEN + CASFW_MAX_FRAME_LEN / 254u + 1u)
#define CASFW_MAX_RATES 32u
#define CASFW_MAX_CHANNELS 16u

/* Sizes of the fixed buffers; a target may override them at compile time. */
#ifndef CASFW_DAC_RING_VALUES /* DAC samples held (frames x channels) */
#define CASFW_DAC_RING_VALUES (1u << 19)
#endif
#ifndef CASFW_DAC_SEGMENTS /* runs of consecutive DAC indices held (gaps + 1) */
#define CASFW_DAC_SEGMENTS 64u
#endif
#ifndef CASFW_TX_BYTES /* encoded bytes waiting for the link: the board's ADC buffer; a host
                          build holds 2 s at 1 MS/s x 2 int16 (a stalled simulation host) */
#define CASFW_TX_BYTES (1u << 23)
#endif
#ifndef CASFW_IO_FRAMES /* most sample frames per call of the HAL's sample_io */
#define CASFW_IO_FRAMES 16384u
#endif

/* Board time in nanoseconds since power-up. */
typedef uint64_t casfw_ns;

/*
 * Hardware abstraction. ctx is passed back to every call.
 *  now_ns:       board time, ns, monotonic.
 *  sample_io:    play n sample frames on the DAC and capture n on the ADC, for the sample
 *                indices first .. first+n-1: dac holds n x n_dac full-scale values
 *                (interleaved, +-1.0 full scale, 0.0 where the DAC had nothing), adc receives
 *                n x n_adc full-scale values (before the ADC gain).
 *  stream_start: a stream begins (a target may reset its analog path; may be NULL).
 */
typedef struct {
    void *ctx;
    casfw_ns (*now_ns)(void *ctx);
    void (*sample_io)(void *ctx, uint64_t first, uint32_t n, const double *dac, unsigned n_dac,
                      double *adc, unsigned n_adc);
    void (*stream_start)(void *ctx);
} casfw_hal;

/* What the board is: CAPABILITIES, identity and the reporting intervals. */
typedef struct {
    uint8_t dac_channels, adc_channels;
    uint8_t formats; /* bit (code - 1) per supported sample format */
    uint8_t n_rates;
    uint32_t sample_rates_hz[CASFW_MAX_RATES];
    uint32_t dac_buffer_samples, adc_buffer_samples;
    uint16_t max_frame_len;
    int16_t gain_min_cdb, gain_max_cdb;
    uint8_t fw_major, fw_minor;
    uint16_t fw_patch;
    uint32_t board_serial;
    uint64_t sync_interval_ns, status_interval_ns;
    int16_t temperature_cdeg;
} casfw_config;

typedef enum {
    CASFW_IDLE = 0,
    CASFW_READY,
    CASFW_CONFIGURED,
    CASFW_STREAMING,
    CASFW_STOPPED
} casfw_state;

typedef struct {
    uint64_t first; /* sample index of the first frame held */
    uint32_t count; /* frames held */
} casfw_segment;

/* Configuration acknowledged by CONFIGURE. */
typedef struct {
    uint32_t rate;
    uint16_t dac_mask, adc_mask;
    uint8_t dac_format, adc_format;
    int16_t dac_gain_cdb, adc_gain_cdb;
    unsigned n_dac, n_adc;
    double dac_gain, adc_gain;
} casfw_setup;

typedef struct {
    casfw_config cfg;
    casfw_hal hal;
    casfw_state state;
    int configured;
    casfw_setup setup;
    uint16_t tx_seq;
    /* sample clock: index(t) = base_index + (t - base_ns) * rate (SPEC 5.3) */
    uint32_t rate;
    uint64_t base_index;
    casfw_ns base_ns;
    /* DAC FIFO: samples in arrival order, as segments of consecutive indices */
    uint32_t dac_values[CASFW_DAC_RING_VALUES]; /* raw wire samples (int or float bits) */
    uint32_t ring_read, ring_used;              /* in values */
    casfw_segment seg[CASFW_DAC_SEGMENTS];
    unsigned seg_head, seg_n;
    uint32_t dac_level; /* frames queued */
    int have_dac_end;
    uint64_t dac_end; /* index after the last DAC sample accepted */
    uint32_t credit;  /* outstanding: granted - spent */
    /* streaming */
    int capturing;
    uint64_t produced; /* next index to play and capture */
    int in_underrun;
    int in_overrun; /* the last ADC_DATA frame was lost: a run of lost indices goes on */
    uint32_t dac_underruns, adc_overruns;
    /* ADC values clipped at conversion since power-up (every channel): the count behind the
     * latched ADC_CLIPPING alarm; not on the wire (STATUS carries the alarm bit only). */
    uint32_t adc_clipped_samples;
    uint16_t latched;
    /* watchdog and periodic messages */
    int wd_armed;
    uint64_t wd_ns;
    casfw_ns last_host;
    casfw_ns last_now; /* board time never goes back, whatever the HAL's clock does */
    int periodic;
    casfw_ns next_sync, next_status;
    /* receiver */
    uint8_t rx[CASFW_MAX_ENCODED + 1];
    uint8_t decoded[CASFW_MAX_ENCODED]; /* COBS-decoded frame being handled */
    size_t rx_len;
    int rx_discarding;
    uint32_t frame_errors, frames_ok;
    /* transmitter */
    uint8_t frame[CASFW_MAX_FRAME_LEN];
    uint8_t tx[CASFW_TX_BYTES];
    size_t tx_len;
    /* scratch of the sample path: CASFW_IO_FRAMES frames of every channel */
    double dac_scratch[CASFW_IO_FRAMES * CASFW_MAX_CHANNELS];
    double adc_scratch[CASFW_IO_FRAMES * CASFW_MAX_CHANNELS];
} casfw_board;

/* Power-up: state IDLE, sample clock 0 at the first rate of cfg. */
void casfw_init(casfw_board *b, const casfw_config *cfg, const casfw_hal *hal);
/* Bytes from the host, any chunking; handles every complete frame at once. */
void casfw_receive(casfw_board *b, const uint8_t *data, size_t n);
/* The service pass of SPEC 5: watchdog, sample path, SYNC, STATUS, credit. */
void casfw_service(casfw_board *b);
/* Moves up to cap bytes for the host into out; returns the count. */
size_t casfw_take_output(casfw_board *b, uint8_t *out, size_t cap);
/* Bytes waiting for the link. */
size_t casfw_pending_output(const casfw_board *b);
/* The host link went away (a transport with a connect event): back to IDLE. */
void casfw_link_lost(casfw_board *b);
/* The sample clock at board time t (SPEC 5.3). */
uint64_t casfw_index_at(const casfw_board *b, casfw_ns t);

/* Wire helpers (casfw_wire.c), exported for tests. */
uint32_t casfw_crc32(const uint8_t *p, size_t n, uint32_t seed);
size_t casfw_cobs_encode(const uint8_t *in, size_t n, uint8_t *out);
/* Returns the decoded length, or (size_t)-1 if a block runs past the end. */
size_t casfw_cobs_decode(const uint8_t *in, size_t n, uint8_t *out);

/* The reference board of the golden conversations and of `hil sim-serve board --impl c`. */
void casfw_default_config(casfw_config *cfg);

#endif
