/* Framing primitives of SPEC section 1: CRC-32 with a seed, canonical COBS. */
#include "casfw.h"

static uint32_t crc_table[256];
static int crc_ready;

static void crc_init(void) {
    for (uint32_t i = 0; i < 256u; i++) {
        uint32_t c = i;
        for (int k = 0; k < 8; k++) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
        crc_table[i] = c;
    }
    crc_ready = 1;
}

/* zlib.crc32(p[:n], seed): the running-CRC convention of SPEC 1.2, table-driven. */
uint32_t casfw_crc32(const uint8_t *p, size_t n, uint32_t seed) {
    if (!crc_ready) crc_init();
    uint32_t c = seed ^ 0xFFFFFFFFu;
    while (n--) c = crc_table[(c ^ *p++) & 0xFFu] ^ (c >> 8);
    return c ^ 0xFFFFFFFFu;
}

/* Canonical COBS: a block of 254 data bytes ending the input gets no trailing 0x01 block. */
size_t casfw_cobs_encode(const uint8_t *in, size_t n, uint8_t *out) {
    size_t o = 1, code_pos = 0;
    uint8_t code = 1;
    for (size_t i = 0; i < n; i++) {
        if (in[i] == 0) {
            out[code_pos] = code;
            code_pos = o++;
            code = 1;
            continue;
        }
        out[o++] = in[i];
        if (++code == 0xFFu) {
            out[code_pos] = code;
            if (i + 1 == n) return o;
            code_pos = o++;
            code = 1;
        }
    }
    out[code_pos] = code;
    return o;
}

size_t casfw_cobs_decode(const uint8_t *in, size_t n, uint8_t *out) {
    size_t i = 0, o = 0;
    while (i < n) {
        uint8_t code = in[i++];
        if (code == 0) return (size_t)-1;
        for (uint8_t k = 1; k < code; k++) {
            if (i >= n) return (size_t)-1;
            out[o++] = in[i++];
        }
        if (code != 0xFFu && i < n) out[o++] = 0;
    }
    return o;
}
