/* Protocol v1 (docs/protocol.md): frame types and payload lengths, in C, so that the firmware (C++,
 * protocol.h) and the simavr harness (C, sim_devices/avr/avr_harness.c) read them from one place;
 * tests/firmware/test_protocol_ids.py checks them against the host's rehab_hil.protocol. */
#ifndef REHAB_PROTOCOL_IDS_H
#define REHAB_PROTOCOL_IDS_H
#include <stdint.h>

#define PROTO_VERSION 1

/* host -> device */
#define PROTO_T_HELLO_REQ 0x01
#define PROTO_T_CONFIGURE 0x02
#define PROTO_T_COMMAND 0x03
#define PROTO_T_HEARTBEAT_REQ 0x04
#define PROTO_T_ESTOP 0x05
#define PROTO_T_CLEAR 0x06
#define PROTO_T_SET_ENCODER 0x07
/* device -> host */
#define PROTO_T_HELLO 0x81
#define PROTO_T_SAMPLE 0x82
#define PROTO_T_FAULT 0x83
#define PROTO_T_HEARTBEAT 0x84
#define PROTO_T_ACK 0x85

/* payload bytes */
#define PROTO_LEN_CONFIGURE 24
#define PROTO_LEN_COMMAND 6
#define PROTO_LEN_HEARTBEAT_REQ 4
#define PROTO_LEN_SET_ENCODER 4
#define PROTO_LEN_HELLO 14
#define PROTO_LEN_SAMPLE 29
#define PROTO_LEN_FAULT 4
#define PROTO_LEN_HEARTBEAT 4
#define PROTO_LEN_ACK 4

/* The payload length the firmware accepts for a host frame type; -1: not a type the host sends.
 * The firmware counts a host frame of any other length, or type, as bad and answers nothing. */
static inline int proto_host_payload_len(uint8_t type) {
  switch (type) {
    case PROTO_T_HELLO_REQ: case PROTO_T_ESTOP: case PROTO_T_CLEAR: return 0;
    case PROTO_T_CONFIGURE: return PROTO_LEN_CONFIGURE;
    case PROTO_T_COMMAND: return PROTO_LEN_COMMAND;
    case PROTO_T_HEARTBEAT_REQ: return PROTO_LEN_HEARTBEAT_REQ;
    case PROTO_T_SET_ENCODER: return PROTO_LEN_SET_ENCODER;
    default: return -1;
  }
}

#endif
