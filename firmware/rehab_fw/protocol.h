// Protocol v1 (docs/protocol.md): COBS framing, CRC-16/CCITT-FALSE, packet layout.
// Decoded packet = version:u8 | type:u8 | seq:u16 | payload | crc:u16, little-endian.
#pragma once
#include <stdint.h>
#include <stddef.h>
#include "protocol_ids.h"  // the types and payload lengths, shared with the simavr harness

namespace proto {

const uint8_t VERSION = PROTO_VERSION;
const uint8_t MAX_PACKET = 64;             // decoded bytes, header + payload + crc
const uint8_t HEADER = 4;                  // version, type, seq
const uint8_t OVERHEAD = HEADER + 2;       // + crc
const uint8_t MAX_PAYLOAD = MAX_PACKET - OVERHEAD;
// COBS adds one byte per 254 data bytes (one here), plus the 0x00 delimiter.
const uint8_t MAX_ENCODED = MAX_PACKET + 1;

enum Type : uint8_t {
  HELLO_REQ = PROTO_T_HELLO_REQ, CONFIGURE = PROTO_T_CONFIGURE, COMMAND = PROTO_T_COMMAND,
  HEARTBEAT_REQ = PROTO_T_HEARTBEAT_REQ, ESTOP = PROTO_T_ESTOP, CLEAR = PROTO_T_CLEAR, SET_ENCODER = PROTO_T_SET_ENCODER,
  HELLO = PROTO_T_HELLO, SAMPLE = PROTO_T_SAMPLE, FAULT = PROTO_T_FAULT, HEARTBEAT = PROTO_T_HEARTBEAT, ACK = PROTO_T_ACK,
};

const uint8_t LEN_HELLO = PROTO_LEN_HELLO;
const uint8_t LEN_SAMPLE = PROTO_LEN_SAMPLE;

uint16_t crc16(const uint8_t *data, size_t len);

// Little-endian helpers.
inline uint16_t get_u16(const uint8_t *p) { return (uint16_t)p[0] | ((uint16_t)p[1] << 8); }
inline uint32_t get_u32(const uint8_t *p) { return (uint32_t)get_u16(p) | ((uint32_t)get_u16(p + 2) << 16); }
inline void put_u16(uint8_t *p, uint16_t v) { p[0] = (uint8_t)v; p[1] = (uint8_t)(v >> 8); }
inline void put_u32(uint8_t *p, uint32_t v) { put_u16(p, (uint16_t)v); put_u16(p + 2, (uint16_t)(v >> 16)); }

// Incremental frame receiver: feed it bytes; it returns true when a complete, CRC-valid packet
// of protocol version 1 is in packet()/length(). Everything else between two delimiters
// (COBS error, too long, too short, bad CRC, wrong version) bumps bad_frames and is dropped.
// Type/length checks are the caller's (it knows the types); it calls count_bad() for those.
class Receiver {
 public:
  bool feed(uint8_t byte);
  const uint8_t *packet() const { return dec_; }
  uint8_t length() const { return dec_len_; }
  uint16_t bad_frames() const { return bad_; }
  void count_bad() { if (bad_ != 0xFFFF) ++bad_; }

 private:
  bool finish();
  uint8_t enc_[MAX_ENCODED];
  uint8_t dec_[MAX_PACKET];
  uint8_t enc_len_ = 0;
  uint8_t dec_len_ = 0;
  bool overflow_ = false;
  uint16_t bad_ = 0;
};

// Builds a packet (header + payload + crc) and COBS-encodes it with its delimiter into out;
// returns the number of bytes to send (<= MAX_ENCODED + 1).
uint8_t encode_frame(uint8_t type, uint16_t seq, const uint8_t *payload, uint8_t len, uint8_t *out);

}  // namespace proto
