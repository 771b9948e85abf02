/*
 * The device role of protocol 2.0, written from ../SPEC.md: sections 1-4 (wire) and 5
 * (behaviour and timing). Section numbers in comments point into the SPEC.
 */
#include <math.h>
#include <string.h>

#include "casfw.h"

enum {
    T_HELLO = 0x01, T_VERSION = 0x02, T_CAPABILITIES = 0x03,
    T_CONFIGURE = 0x10, T_START = 0x11, T_STOP = 0x12, T_KEEPALIVE = 0x13,
    T_DAC_DATA = 0x20, T_ADC_DATA = 0x21, T_CREDIT = 0x22,
    T_STATUS = 0x30, T_SYNC = 0x31, T_LOG = 0x32, T_ACK = 0x40, T_NAK = 0x41
};
enum {
    NAK_UNKNOWN_MESSAGE = 1, NAK_BAD_PAYLOAD = 2, NAK_BAD_STATE = 3, NAK_UNSUPPORTED_RATE = 4,
    NAK_UNSUPPORTED_CHANNELS = 5, NAK_UNSUPPORTED_FORMAT = 6, NAK_GAIN_OUT_OF_RANGE = 7,
    NAK_CREDIT_EXCEEDED = 8, NAK_START_INDEX_PASSED = 9, NAK_BUSY = 10
};
enum {
    ALARM_WATCHDOG = 0x0002, ALARM_DAC_UNDERRUN = 0x0004, ALARM_ADC_OVERRUN = 0x0008,
    ALARM_ADC_CLIPPING = 0x0010
};
#define FLAG_OPTIONAL 0x01u
#define HEADER 8u
#define OVERHEAD 12u     /* header + CRC */
#define DATA_FIXED 14u   /* fixed part of DAC_DATA / ADC_DATA */
#define NS_PER_S 1000000000ull

/* --- little-endian fields ---------------------------------------------------------------- */
static void put16(uint8_t *p, uint32_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
static void put32(uint8_t *p, uint32_t v) { put16(p, v); put16(p + 2, v >> 16); }
static void put64(uint8_t *p, uint64_t v) { put32(p, (uint32_t)v); put32(p + 4, (uint32_t)(v >> 32)); }
static uint32_t get16(const uint8_t *p) { return (uint32_t)p[0] | ((uint32_t)p[1] << 8); }
static uint32_t get32(const uint8_t *p) { return get16(p) | (get16(p + 2) << 16); }
static uint64_t get64(const uint8_t *p) { return get32(p) | ((uint64_t)get32(p + 4) << 32); }

static unsigned popcount16(uint32_t m) { unsigned n = 0; for (; m; m &= m - 1) n++; return n; }
static unsigned format_size(uint8_t fmt) { return fmt == 1 ? 2u : fmt == 2 ? 3u : 4u; }
static int format_known(uint8_t fmt) { return fmt >= 1 && fmt <= 3; }

static casfw_ns now(casfw_board *b) {
    casfw_ns t = b->hal.now_ns(b->hal.ctx);
    if (t < b->last_now) t = b->last_now;
    b->last_now = t;
    return t;
}

/* --- SPEC 5.3: the sample clock in integer nanoseconds ----------------------------------- */
uint64_t casfw_index_at(const casfw_board *b, casfw_ns t) {
    uint64_t dt = t - b->base_ns;
    return b->base_index + (dt / NS_PER_S) * b->rate + ((dt % NS_PER_S) * b->rate) / NS_PER_S;
}

/* --- sending -------------------------------------------------------------------------------- */
static size_t tx_free(const casfw_board *b) { return CASFW_TX_BYTES - b->tx_len; }
static size_t encoded_bound(size_t n) { return n + n / 254u + 2u; }

/* Frames the payload already in b->frame + HEADER; returns 0 if the link buffer is full. */
static int send_built(casfw_board *b, uint8_t type, size_t payload_len, uint8_t flags) {
    uint8_t *f = b->frame;
    size_t n = HEADER + payload_len;
    if (encoded_bound(n + 4) > tx_free(b)) return 0;
    f[0] = CASFW_PROTOCOL_MAJOR;
    f[1] = CASFW_PROTOCOL_MINOR;
    f[2] = type;
    f[3] = flags;
    put16(f + 4, b->tx_seq);
    put16(f + 6, (uint32_t)payload_len);
    uint32_t seed = (type == T_HELLO || type == T_VERSION) ? 0u : CASFW_SCHEMA_HASH;
    put32(f + n, casfw_crc32(f, n, seed));
    b->tx_len += casfw_cobs_encode(f, n + 4, b->tx + b->tx_len);
    b->tx[b->tx_len++] = 0;
    b->tx_seq = (uint16_t)(b->tx_seq + 1u);
    return 1;
}

static uint8_t *payload(casfw_board *b) { return b->frame + HEADER; }

static void send_ack(casfw_board *b, uint16_t ref_seq, uint8_t ref_type) {
    uint8_t *p = payload(b);
    put16(p, ref_seq);
    p[2] = ref_type;
    send_built(b, T_ACK, 3, 0);
}

static void send_nak(casfw_board *b, uint16_t ref_seq, uint8_t ref_type, uint8_t code,
                     const char *detail) {
    uint8_t *p = payload(b);
    size_t len = strlen(detail);
    if (len > 255u) len = 255u;
    put16(p, ref_seq);
    p[2] = ref_type;
    p[3] = code;
    p[4] = (uint8_t)len;
    memcpy(p + 5, detail, len);
    send_built(b, T_NAK, 5 + len, 0);
}

static void send_sync(casfw_board *b, casfw_ns t) {
    uint8_t *p = payload(b);
    put64(p, casfw_index_at(b, t));
    put64(p + 8, t);
    send_built(b, T_SYNC, 16, 0);
    b->next_sync = t + b->cfg.sync_interval_ns;
}

/* SPEC 5.8: latched bits are reported once, then cleared; DAC_UNDERRUN also while it holds. */
static void send_status(casfw_board *b, casfw_ns t, uint16_t alarms) {
    uint8_t *p = payload(b);
    alarms |= b->latched;
    if (b->capturing && b->in_underrun) alarms |= ALARM_DAC_UNDERRUN;
    b->latched = 0;
    put64(p, casfw_index_at(b, t));
    put32(p + 8, b->dac_level);
    put32(p + 12, 0);
    put32(p + 16, b->dac_underruns);
    put32(p + 20, b->adc_overruns);
    put16(p + 24, (uint16_t)b->cfg.temperature_cdeg);
    put16(p + 26, alarms);
    send_built(b, T_STATUS, 28, 0);
}

static void send_version(casfw_board *b) {
    uint8_t *p = payload(b);
    p[0] = CASFW_PROTOCOL_MAJOR;
    p[1] = CASFW_PROTOCOL_MINOR;
    put32(p + 2, CASFW_SCHEMA_HASH);
    p[6] = b->cfg.fw_major;
    p[7] = b->cfg.fw_minor;
    put16(p + 8, b->cfg.fw_patch);
    put32(p + 10, b->cfg.board_serial);
    send_built(b, T_VERSION, 14, 0);
}

static void send_capabilities(casfw_board *b) {
    const casfw_config *c = &b->cfg;
    uint8_t *p = payload(b);
    p[0] = c->dac_channels;
    p[1] = c->adc_channels;
    p[2] = c->formats;
    p[3] = c->n_rates;
    put32(p + 4, c->dac_buffer_samples);
    put32(p + 8, c->adc_buffer_samples);
    put16(p + 12, c->max_frame_len);
    put16(p + 14, (uint16_t)c->gain_min_cdb);
    put16(p + 16, (uint16_t)c->gain_max_cdb);
    for (unsigned i = 0; i < c->n_rates; i++) put32(p + 18 + 4 * i, c->sample_rates_hz[i]);
    send_built(b, T_CAPABILITIES, 18 + 4u * c->n_rates, 0);
}

/* --- the DAC FIFO (SPEC 5.4) ------------------------------------------------------------- */
static uint32_t ring_capacity(const casfw_board *b) {
    uint32_t per = b->setup.n_dac ? b->setup.n_dac : 1u;
    return (CASFW_DAC_RING_VALUES / per) * per;
}

static void fifo_clear(casfw_board *b) {
    b->ring_read = b->ring_used = 0;
    b->seg_head = b->seg_n = 0;
    b->dac_level = 0;
}

/* Drops up to n frames at the head of the FIFO (late samples). */
static void fifo_drop(casfw_board *b, uint32_t n) {
    while (n && b->seg_n) {
        casfw_segment *s = &b->seg[b->seg_head];
        uint32_t k = n < s->count ? n : s->count;
        uint32_t values = k * b->setup.n_dac;
        b->ring_read = (b->ring_read + values) % ring_capacity(b);
        b->ring_used -= values;
        b->dac_level -= k;
        s->first += k;
        s->count -= k;
        n -= k;
        if (s->count == 0) {
            b->seg_head = (b->seg_head + 1u) % CASFW_DAC_SEGMENTS;
            b->seg_n--;
        }
    }
}

/* Drops every queued frame whose index is below idx. */
static void fifo_drop_before(casfw_board *b, uint64_t idx) {
    while (b->seg_n) {
        casfw_segment *s = &b->seg[b->seg_head];
        if (s->first >= idx) return;
        uint64_t late = idx - s->first;
        fifo_drop(b, late < s->count ? (uint32_t)late : s->count);
    }
}

static double full_scale(const casfw_board *b, uint32_t raw) {
    double x;
    switch (b->setup.dac_format) {
    case 1: x = (double)(int32_t)raw * (1.0 / 32768.0); break;
    case 2: x = (double)(int32_t)raw * (1.0 / 8388608.0); break;
    default: {
        float f;
        memcpy(&f, &raw, sizeof f);
        x = (double)f;
    }
    }
    return b->setup.dac_gain != 1.0 ? x * b->setup.dac_gain : x;
}

/* The DAC output for index idx into out[n_dac]; 1 if a sample was queued for it. */
static int fifo_play(casfw_board *b, uint64_t idx, double *out) {
    unsigned n_dac = b->setup.n_dac;
    fifo_drop_before(b, idx);
    if (b->seg_n && b->seg[b->seg_head].first == idx) {
        uint32_t cap = ring_capacity(b);
        for (unsigned c = 0; c < n_dac; c++)
            out[c] = full_scale(b, b->dac_values[(b->ring_read + c) % cap]);
        fifo_drop(b, 1);
        return 1;
    }
    for (unsigned c = 0; c < n_dac; c++) out[c] = 0.0;
    return 0;
}

/* Queues n frames for indices first.. from wire samples p; 0 if no segment is free. */
static int fifo_push(casfw_board *b, uint64_t first, const uint8_t *p, uint32_t n) {
    if (n == 0) return 1;
    casfw_segment *last = b->seg_n ? &b->seg[(b->seg_head + b->seg_n - 1u) % CASFW_DAC_SEGMENTS]
                                   : NULL;
    if (last && last->first + last->count == first) {
        last->count += n;
    } else {
        if (b->seg_n == CASFW_DAC_SEGMENTS) return 0;
        casfw_segment *s = &b->seg[(b->seg_head + b->seg_n) % CASFW_DAC_SEGMENTS];
        s->first = first;
        s->count = n;
        b->seg_n++;
    }
    uint32_t cap = ring_capacity(b);
    unsigned size = format_size(b->setup.dac_format);
    uint32_t values = n * b->setup.n_dac;
    uint32_t w = (b->ring_read + b->ring_used) % cap;
    for (uint32_t i = 0; i < values; i++, p += size) {
        uint32_t raw;
        if (size == 2) raw = (uint32_t)(int32_t)(int16_t)get16(p);
        else if (size == 3) raw = (uint32_t)(((int32_t)(get16(p) | ((uint32_t)p[2] << 16)) << 8) >> 8);
        else raw = get32(p);
        b->dac_values[w] = raw;
        w = (w + 1u == cap) ? 0u : w + 1u;
    }
    b->ring_used += values;
    b->dac_level += n;
    return 1;
}

/* --- sample path ---------------------------------------------------------------------------- */
static void count_underrun(casfw_board *b, int covered) {
    if (!covered && !b->in_underrun) {
        b->dac_underruns++;
        b->latched |= ALARM_DAC_UNDERRUN;
    }
    b->in_underrun = !covered;
}

static void put_adc_sample(casfw_board *b, uint8_t *p, double v) {
    if (b->setup.adc_gain != 1.0) v *= b->setup.adc_gain;
    uint8_t fmt = b->setup.adc_format;
    if (fmt == 3) {
        float f = (float)v;
        uint32_t bits;
        memcpy(&bits, &f, sizeof bits);
        put32(p, bits);
        return;
    }
    double scale = fmt == 1 ? 32768.0 : 8388608.0;
    double r = rint(v * scale);
    if (r != r) r = 0.0; /* NaN from a FLOAT32 DAC stream: silence */
    if (r > scale - 1.0 || r < -scale) {
        b->latched |= ALARM_ADC_CLIPPING;
        b->adc_clipped_samples++;
        r = r > 0 ? scale - 1.0 : -scale;
    }
    int32_t count = (int32_t)r;
    if (fmt == 1) put16(p, (uint32_t)count);
    else { put16(p, (uint32_t)count); p[2] = (uint8_t)((uint32_t)count >> 16); }
}

/* Plays the DAC and runs the HAL's sample I/O for up to CASFW_IO_FRAMES indices from first
 * (at most up to end), leaving the ADC values in adc_scratch. */
static uint32_t convert(casfw_board *b, uint64_t first, uint64_t end) {
    const casfw_setup *s = &b->setup;
    uint32_t m = end - first < CASFW_IO_FRAMES ? (uint32_t)(end - first) : CASFW_IO_FRAMES;
    for (uint32_t i = 0; i < m; i++)
        count_underrun(b, fifo_play(b, first + i, b->dac_scratch + (size_t)i * s->n_dac));
    b->hal.sample_io(b->hal.ctx, first, m, b->dac_scratch, s->n_dac, b->adc_scratch, s->n_adc);
    return m;
}

/* Plays and captures every index up to end, sending ADC_DATA frames (SPEC 5.4): frames of
 * `step` sample frames from the first index produced; the HAL converts in spans of up to
 * CASFW_IO_FRAMES, independent of the frame cuts. */
static void capture_until(casfw_board *b, uint64_t end) {
    const casfw_setup *s = &b->setup;
    unsigned size = format_size(s->adc_format);
    unsigned frame_bytes = s->n_adc * size;
    uint32_t step = (b->cfg.max_frame_len - OVERHEAD - DATA_FIXED) / frame_bytes;
    uint32_t io_len = 0, io_pos = 0;
    while (b->produced < end) {
        uint64_t first = b->produced;
        uint32_t n = end - first < step ? (uint32_t)(end - first) : step;
        uint8_t *p = payload(b);
        put64(p, first);
        put16(p + 8, n);
        put16(p + 10, s->adc_mask);
        p[12] = s->adc_format;
        p[13] = 0;
        uint8_t *q = p + DATA_FIXED;
        for (uint32_t done = 0; done < n;) {
            if (io_pos == io_len) {
                io_len = convert(b, first + done, end);
                io_pos = 0;
            }
            uint32_t k = n - done < io_len - io_pos ? n - done : io_len - io_pos;
            const double *v = b->adc_scratch + (size_t)io_pos * s->n_adc;
            for (uint32_t i = 0; i < k * s->n_adc; i++, q += size) put_adc_sample(b, q, v[i]);
            io_pos += k;
            done += k;
        }
        b->produced = first + n;
        if (!send_built(b, T_ADC_DATA, DATA_FIXED + (size_t)n * frame_bytes, 0)) {
            /* The link buffer is full: these samples are lost. SPEC 5.4: one overrun per
               run of consecutive lost indices, however many frames it spans. */
            if (!b->in_overrun) b->adc_overruns++;
            b->in_overrun = 1;
            b->latched |= ALARM_ADC_OVERRUN;
        } else {
            b->in_overrun = 0;
        }
    }
}

/* --- session ------------------------------------------------------------------------------- */
static void stop_output(casfw_board *b) {
    b->capturing = 0;
    b->in_underrun = 0;
    b->in_overrun = 0;
    b->have_dac_end = 0;
    fifo_clear(b);
}

/* SPEC 5.5: grant the free DAC buffer once it is at least 1/8 of it. */
static void grant_credit(casfw_board *b) {
    if (!b->configured) return;
    if (b->state != CASFW_CONFIGURED && b->state != CASFW_STREAMING && b->state != CASFW_STOPPED)
        return;
    int64_t free_frames = (int64_t)b->cfg.dac_buffer_samples - b->dac_level - b->credit;
    int64_t least = b->cfg.dac_buffer_samples / 8u ? b->cfg.dac_buffer_samples / 8u : 1;
    if (free_frames < least) return;
    put32(payload(b), (uint32_t)free_frames);
    if (send_built(b, T_CREDIT, 4, 0)) b->credit += (uint32_t)free_frames;
}

static void unconfigure(casfw_board *b) {
    stop_output(b);
    b->configured = 0;
    b->credit = 0;
}

static void new_session(casfw_board *b, casfw_state state) {
    unconfigure(b);
    b->state = state;
    b->wd_armed = 0;
    b->latched = 0;
    b->periodic = 0;
    b->tx_seq = 0;
}

void casfw_link_lost(casfw_board *b) {
    new_session(b, CASFW_IDLE);
    b->tx_len = 0;
    b->rx_len = 0;
    b->rx_discarding = 0;
}

/* --- commands --------------------------------------------------------------------------- */
static void on_hello(casfw_board *b, const uint8_t *p) {
    int compatible = p[0] == CASFW_PROTOCOL_MAJOR && get32(p + 2) == CASFW_SCHEMA_HASH;
    new_session(b, compatible ? CASFW_READY : CASFW_IDLE);
    send_version(b);
    if (!compatible) return;
    send_capabilities(b);
    b->periodic = 1;
    b->next_sync = b->next_status = now(b);
}

static int rate_supported(const casfw_config *c, uint32_t rate) {
    for (unsigned i = 0; i < c->n_rates; i++)
        if (c->sample_rates_hz[i] == rate) return 1;
    return 0;
}

static void on_configure(casfw_board *b, uint16_t seq, const uint8_t *p) {
    const casfw_config *c = &b->cfg;
    uint32_t rate = get32(p);
    uint16_t dac_mask = (uint16_t)get16(p + 4), adc_mask = (uint16_t)get16(p + 6);
    uint8_t dac_fmt = p[8], adc_fmt = p[9];
    int16_t dac_gain = (int16_t)get16(p + 10), adc_gain = (int16_t)get16(p + 12);
    unconfigure(b);
    b->state = CASFW_READY;
    if (!rate_supported(c, rate)) {
        send_nak(b, seq, T_CONFIGURE, NAK_UNSUPPORTED_RATE, "rate not in CAPABILITIES");
        return;
    }
    if ((dac_mask >> c->dac_channels) || (adc_mask >> c->adc_channels)) {
        send_nak(b, seq, T_CONFIGURE, NAK_UNSUPPORTED_CHANNELS, "channel beyond the board's");
        return;
    }
    if (!(c->formats & (1u << (dac_fmt - 1))) || !(c->formats & (1u << (adc_fmt - 1)))) {
        send_nak(b, seq, T_CONFIGURE, NAK_UNSUPPORTED_FORMAT, "format not in CAPABILITIES");
        return;
    }
    if (dac_gain < c->gain_min_cdb || dac_gain > c->gain_max_cdb || adc_gain < c->gain_min_cdb
        || adc_gain > c->gain_max_cdb) {
        send_nak(b, seq, T_CONFIGURE, NAK_GAIN_OUT_OF_RANGE, "gain outside CAPABILITIES");
        return;
    }
    casfw_ns t = now(b);
    b->base_index = casfw_index_at(b, t);
    b->base_ns = t;
    b->rate = rate;
    casfw_setup *s = &b->setup;
    s->rate = rate;
    s->dac_mask = dac_mask;
    s->adc_mask = adc_mask;
    s->dac_format = dac_fmt;
    s->adc_format = adc_fmt;
    s->dac_gain_cdb = dac_gain;
    s->adc_gain_cdb = adc_gain;
    s->n_dac = popcount16(dac_mask);
    s->n_adc = popcount16(adc_mask);
    s->dac_gain = pow(10.0, dac_gain / 2000.0);
    s->adc_gain = pow(10.0, adc_gain / 2000.0);
    send_ack(b, seq, T_CONFIGURE);
    b->state = CASFW_CONFIGURED;
    b->configured = 1;
    fifo_clear(b);
    send_sync(b, t);
    grant_credit(b);
}

static void on_start(casfw_board *b, uint16_t seq, const uint8_t *p) {
    uint64_t start = get64(p);
    uint64_t at = casfw_index_at(b, now(b));
    if (start < at) {
        b->state = CASFW_CONFIGURED;
        send_nak(b, seq, T_START, NAK_START_INDEX_PASSED, "the clock is past it; start later");
        return;
    }
    b->produced = start;
    b->capturing = 1;
    b->in_underrun = 0;
    b->in_overrun = 0;
    fifo_drop_before(b, start);
    if (b->hal.stream_start) b->hal.stream_start(b->hal.ctx);
    send_ack(b, seq, T_START);
    b->state = CASFW_STREAMING;
}

static void on_stop(casfw_board *b, uint16_t seq) {
    if (b->capturing) capture_until(b, casfw_index_at(b, now(b)));
    send_ack(b, seq, T_STOP);
    b->state = CASFW_STOPPED;
    b->credit = 0;
    stop_output(b);
    grant_credit(b);
}

static void on_dac_data(casfw_board *b, uint16_t seq, const uint8_t *p, uint32_t n) {
    uint64_t first = get64(p);
    if (b->have_dac_end && first < b->dac_end) {
        send_nak(b, seq, T_DAC_DATA, NAK_BAD_PAYLOAD, "overlaps DAC data already accepted");
        return;
    }
    b->have_dac_end = 1;
    b->dac_end = first + n;
    const uint8_t *samples = p + DATA_FIXED;
    uint32_t late = 0;
    if (b->capturing && b->produced > first)
        late = b->produced - first < n ? (uint32_t)(b->produced - first) : n;
    size_t frame_bytes = (size_t)b->setup.n_dac * format_size(b->setup.dac_format);
    if (!fifo_push(b, first + late, samples + late * frame_bytes, n - late))
        send_nak(b, seq, T_DAC_DATA, NAK_BUSY, "too many gaps queued");
}

/* --- receiving (SPEC 5.2) ------------------------------------------------------------------ */
static int legal(casfw_state s, uint8_t type) {
    switch (type) {
    case T_HELLO: return 1;
    case T_CONFIGURE: return s == CASFW_READY || s == CASFW_CONFIGURED || s == CASFW_STOPPED;
    case T_START: return s == CASFW_CONFIGURED || s == CASFW_STOPPED;
    case T_STOP:
    case T_DAC_DATA: return s == CASFW_CONFIGURED || s == CASFW_STREAMING || s == CASFW_STOPPED;
    case T_KEEPALIVE: return s != CASFW_IDLE;
    default: return 0;
    }
}

static int device_type(uint8_t t) {
    return t == T_VERSION || t == T_CAPABILITIES || t == T_ADC_DATA || t == T_CREDIT
        || t == T_STATUS || t == T_SYNC || t == T_LOG || t == T_ACK || t == T_NAK;
}

static int host_type(uint8_t t) {
    return t == T_HELLO || t == T_CONFIGURE || t == T_START || t == T_STOP || t == T_KEEPALIVE
        || t == T_DAC_DATA;
}

/* Refuses a frame: one NAK in a session, silence in IDLE. */
static void refuse(casfw_board *b, uint16_t seq, uint8_t type, uint8_t code, const char *why) {
    if (b->state == CASFW_IDLE) return;
    b->last_host = now(b);
    send_nak(b, seq, type, code, why);
}

/* Checks a payload against its layout and allowed ranges (section 3); 1 if good. */
static int payload_ok(const casfw_board *b, uint8_t type, const uint8_t *p, size_t n) {
    (void)b;
    switch (type) {
    case T_HELLO: return n >= 6;
    case T_START: return n >= 8;
    case T_STOP: return 1;
    case T_KEEPALIVE: return n >= 2 && get16(p) >= 1;
    case T_CONFIGURE: {
        if (n < 14) return 0;
        uint32_t rate = get32(p);
        int16_t g1 = (int16_t)get16(p + 10), g2 = (int16_t)get16(p + 12);
        return rate >= 1 && rate <= 100000000u && get16(p + 4) && get16(p + 6)
            && format_known(p[8]) && format_known(p[9]) && g1 >= -12000 && g1 <= 12000
            && g2 >= -12000 && g2 <= 12000;
    }
    case T_DAC_DATA: {
        if (n < DATA_FIXED || !format_known(p[12])) return 0;
        uint32_t count = get16(p + 8), mask = get16(p + 10);
        size_t frame_bytes = (size_t)popcount16(mask) * format_size(p[12]);
        size_t most = frame_bytes ? (CASFW_MAX_FRAME_LEN - OVERHEAD - DATA_FIXED) / frame_bytes : 0;
        return mask && count >= 1 && count <= most && n - DATA_FIXED >= count * frame_bytes;
    }
    default: return 0;
    }
}

static void handle_frame(casfw_board *b, const uint8_t *f, size_t len) {
    uint8_t major = f[0], type = f[2], flags = f[3];
    uint16_t seq = (uint16_t)get16(f + 4);
    const uint8_t *p = f + HEADER;
    size_t n = len - OVERHEAD;
    if (!host_type(type) && !device_type(type)) {
        if (b->state == CASFW_IDLE) return;
        b->last_host = now(b);
        if (!(flags & FLAG_OPTIONAL)) send_nak(b, seq, type, NAK_UNKNOWN_MESSAGE, "unknown type");
        return;
    }
    if (major != CASFW_PROTOCOL_MAJOR && type != T_HELLO && type != T_VERSION) {
        refuse(b, seq, type, NAK_BAD_PAYLOAD, "another protocol major version; send HELLO");
        return;
    }
    if (device_type(type)) {
        refuse(b, seq, type, NAK_BAD_STATE, "only the device sends this type");
        return;
    }
    if (!legal(b->state, type)) {
        refuse(b, seq, type, NAK_BAD_STATE, "not legal in this state (SPEC 5.2)");
        return;
    }
    if (!payload_ok(b, type, p, n)) {
        if (type == T_CONFIGURE) {
            unconfigure(b);
            b->state = CASFW_READY;
        } else if (type == T_START) {
            b->state = CASFW_CONFIGURED;
        }
        refuse(b, seq, type, NAK_BAD_PAYLOAD, "short payload or a field out of range");
        return;
    }
    if (type == T_DAC_DATA) {
        uint32_t count = get16(p + 8);
        if (get16(p + 10) != b->setup.dac_mask || p[12] != b->setup.dac_format) {
            refuse(b, seq, type, NAK_BAD_PAYLOAD, "channel_mask or format differ from CONFIGURE");
            return;
        }
        if (count > b->credit) {
            refuse(b, seq, type, NAK_CREDIT_EXCEEDED, "more samples than the credit left");
            return;
        }
        b->credit -= count;
    }
    b->last_host = now(b);
    switch (type) {
    case T_HELLO: on_hello(b, p); break;
    case T_CONFIGURE: on_configure(b, seq, p); break;
    case T_START: on_start(b, seq, p); break;
    case T_STOP: on_stop(b, seq); break;
    case T_KEEPALIVE:
        b->wd_armed = 1;
        b->wd_ns = (uint64_t)get16(p) * 1000000u;
        break;
    case T_DAC_DATA: on_dac_data(b, seq, p, get16(p + 8)); break;
    default: break;
    }
}

/* Section 1.3: COBS, length, CRC with its seed, payload_length; damaged frames are dropped. */
static void handle_encoded(casfw_board *b, const uint8_t *enc, size_t n) {
    uint8_t *raw = b->decoded;
    size_t len = casfw_cobs_decode(enc, n, raw);
    if (len == (size_t)-1 || len > b->cfg.max_frame_len || len < OVERHEAD) {
        b->frame_errors++;
        return;
    }
    uint8_t type = raw[2];
    uint32_t seed = (type == T_HELLO || type == T_VERSION) ? 0u : CASFW_SCHEMA_HASH;
    if (casfw_crc32(raw, len - 4, seed) != get32(raw + len - 4) || get16(raw + 6) != len - OVERHEAD) {
        b->frame_errors++;
        return;
    }
    b->frames_ok++;
    handle_frame(b, raw, len);
}

void casfw_receive(casfw_board *b, const uint8_t *data, size_t n) {
    size_t limit = (size_t)b->cfg.max_frame_len + b->cfg.max_frame_len / 254u + 1u;
    while (n) {
        const uint8_t *zero = memchr(data, 0, n);
        size_t chunk = zero ? (size_t)(zero - data) : n;
        if (!b->rx_discarding) {
            if (b->rx_len + chunk > limit) {
                b->rx_discarding = 1; /* oversize: drop up to the next delimiter */
                b->frame_errors++;
                b->rx_len = 0;
            } else {
                memcpy(b->rx + b->rx_len, data, chunk);
                b->rx_len += chunk;
            }
        }
        if (!zero) return;
        if (!b->rx_discarding && b->rx_len) handle_encoded(b, b->rx, b->rx_len);
        b->rx_discarding = 0;
        b->rx_len = 0;
        data += chunk + 1;
        n -= chunk + 1;
    }
}

/* --- SPEC 5: the service pass ------------------------------------------------------------- */
static void check_watchdog(casfw_board *b, casfw_ns t) {
    if (!b->wd_armed) return;
    casfw_ns deadline = b->last_host + b->wd_ns;
    if (t <= deadline) return;
    if (b->capturing) capture_until(b, casfw_index_at(b, deadline));
    b->wd_armed = 0;
    int streaming = b->state == CASFW_STREAMING;
    stop_output(b);
    send_status(b, deadline, ALARM_WATCHDOG);
    if (streaming) {
        b->state = CASFW_STOPPED;
        b->credit = 0;
    }
}

void casfw_service(casfw_board *b) {
    if (b->state == CASFW_IDLE) return;
    casfw_ns t = now(b);
    check_watchdog(b, t);
    if (b->capturing) capture_until(b, casfw_index_at(b, t));
    if (b->periodic && t >= b->next_sync) send_sync(b, t);
    if (b->periodic && t >= b->next_status) {
        send_status(b, t, 0);
        b->next_status = t + b->cfg.status_interval_ns;
    }
    grant_credit(b);
}

size_t casfw_take_output(casfw_board *b, uint8_t *out, size_t cap) {
    size_t n = b->tx_len < cap ? b->tx_len : cap;
    memcpy(out, b->tx, n);
    memmove(b->tx, b->tx + n, b->tx_len - n);
    b->tx_len -= n;
    return n;
}

size_t casfw_pending_output(const casfw_board *b) { return b->tx_len; }

void casfw_init(casfw_board *b, const casfw_config *cfg, const casfw_hal *hal) {
    b->cfg = *cfg;
    b->hal = *hal;
    if (b->cfg.n_rates > CASFW_MAX_RATES) b->cfg.n_rates = CASFW_MAX_RATES;
    if (b->cfg.max_frame_len > CASFW_MAX_FRAME_LEN) b->cfg.max_frame_len = CASFW_MAX_FRAME_LEN;
    uint32_t most = CASFW_DAC_RING_VALUES / (cfg->dac_channels ? cfg->dac_channels : 1u);
    if (b->cfg.dac_buffer_samples > most) b->cfg.dac_buffer_samples = most;
    memset(&b->setup, 0, sizeof b->setup);
    b->rate = b->cfg.sample_rates_hz[0];
    b->base_index = 0;
    b->last_now = 0;
    b->base_ns = now(b);
    b->dac_underruns = b->adc_overruns = 0;
    b->adc_clipped_samples = 0;
    b->in_overrun = 0;
    b->frame_errors = b->frames_ok = 0;
    b->tx_len = 0;
    b->rx_len = 0;
    b->rx_discarding = 0;
    b->produced = 0;
    b->last_host = b->base_ns;
    new_session(b, CASFW_IDLE);
}

void casfw_default_config(casfw_config *c) {
    static const uint32_t rates[] = {1000000u, 500000u, 250000u, 192000u, 96000u, 48000u};
    memset(c, 0, sizeof *c);
    c->dac_channels = 2;
    c->adc_channels = 2;
    c->formats = 0x7;
    c->n_rates = (uint8_t)(sizeof rates / sizeof rates[0]);
    memcpy(c->sample_rates_hz, rates, sizeof rates);
    c->dac_buffer_samples = 1u << 18;
    c->adc_buffer_samples = 1u << 16;
    c->max_frame_len = CASFW_MAX_FRAME_LEN;
    c->gain_min_cdb = -4000;
    c->gain_max_cdb = 4000;
    c->fw_major = 1;
    c->fw_minor = 0;
    c->fw_patch = 0;
    c->board_serial = 0x0B0A4D01u;
    c->sync_interval_ns = 100000000u;
    c->status_interval_ns = 250000000u;
    c->temperature_cdeg = 3150;
}
