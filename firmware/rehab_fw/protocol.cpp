#include "protocol.h"

namespace proto {

uint16_t crc16(const uint8_t *data, size_t len) {
  // CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, MSB first, no final xor. Bitwise on purpose:
  // a 512-byte table would cost a quarter of the Uno's RAM (or PROGMEM reads); 64-byte packets
  // at 1 kHz take ~8 % of the CPU this way.
  uint16_t crc = 0xFFFF;
  for (size_t i = 0; i < len; ++i) {
    crc ^= (uint16_t)data[i] << 8;
    for (uint8_t b = 0; b < 8; ++b) crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
  }
  return crc;
}

bool Receiver::feed(uint8_t byte) {
  if (byte != 0) {
    if (enc_len_ < MAX_ENCODED) enc_[enc_len_++] = byte;
    else overflow_ = true;  // keep discarding until the next delimiter resynchronises us
    return false;
  }
  bool ok = finish();
  enc_len_ = 0;
  overflow_ = false;
  return ok;
}

bool Receiver::finish() {
  // An empty frame (two delimiters in a row) is line noise-free padding a host may send to
  // resynchronise; it is neither a packet nor an error.
  if (enc_len_ == 0 && !overflow_) return false;
  if (overflow_) { count_bad(); return false; }
  // COBS decode: each code byte c says "c-1 data bytes follow, then an implicit zero"
  // (no zero after a 0xFF block or at the very end).
  uint8_t i = 0, n = 0;
  while (i < enc_len_) {
    uint8_t code = enc_[i++];
    if (code == 0 || (uint16_t)i + code - 1 > enc_len_) { count_bad(); return false; }
    for (uint8_t k = 1; k < code; ++k) {
      if (n >= MAX_PACKET) { count_bad(); return false; }
      dec_[n++] = enc_[i++];
    }
    if (code != 0xFF && i < enc_len_) {
      if (n >= MAX_PACKET) { count_bad(); return false; }
      dec_[n++] = 0;
    }
  }
  if (n < OVERHEAD) { count_bad(); return false; }
  if (crc16(dec_, n - 2) != get_u16(dec_ + n - 2)) { count_bad(); return false; }
  if (dec_[0] != VERSION) { count_bad(); return false; }
  dec_len_ = n;
  return true;
}

uint8_t encode_frame(uint8_t type, uint16_t seq, const uint8_t *payload, uint8_t len, uint8_t *out) {
  uint8_t pkt[MAX_PACKET];
  if (len > MAX_PAYLOAD) len = MAX_PAYLOAD;
  pkt[0] = VERSION;
  pkt[1] = type;
  put_u16(pkt + 2, seq);
  for (uint8_t i = 0; i < len; ++i) pkt[HEADER + i] = payload[i];
  uint8_t n = HEADER + len;
  put_u16(pkt + n, crc16(pkt, n));
  n += 2;
  // COBS encode (packets are < 254 bytes, so no 0xFF blocks).
  uint8_t code_at = 0, o = 1, code = 1;
  for (uint8_t i = 0; i < n; ++i) {
    if (pkt[i] == 0) {
      out[code_at] = code;
      code_at = o++;
      code = 1;
    } else {
      out[o++] = pkt[i];
      ++code;
    }
  }
  out[code_at] = code;
  out[o++] = 0;
  return o;
}

}  // namespace proto
