// Compile-time check: refuse a build whose serial receive buffer is not the one protocol v1 needs.
//
// Why: at 1 Mbaud a byte arrives every 10 us, and loop() can be busy several hundred us encoding a
// SAMPLE; the core's default 64-byte buffer lasts 640 us and overruns (firmware/README.md, flood
// test). firmware/Makefile passes -DSERIAL_RX_BUFFER_SIZE=256 to every translation unit (the core
// too). An Arduino-IDE build does not, and would silently get 64 bytes: it stops here instead.
// In the IDE, add -DSERIAL_RX_BUFFER_SIZE=256 to compiler.c.extra_flags and compiler.cpp.extra_flags
// (platform.local.txt) so that the core's HardwareSerial is built with it as well; this check can
// only see the value the sketch itself is compiled with.
#ifndef REHAB_FW_RX_BUFFER_CHECK_H
#define REHAB_FW_RX_BUFFER_CHECK_H

#include <Arduino.h>  // HardwareSerial.h: defines SERIAL_RX_BUFFER_SIZE (64 unless given)

#define REHAB_FW_RX_BUFFER_BYTES 256

#if !defined(SERIAL_RX_BUFFER_SIZE)
#error "SERIAL_RX_BUFFER_SIZE is not defined: build with firmware/Makefile (make firmware)"
#elif SERIAL_RX_BUFFER_SIZE != REHAB_FW_RX_BUFFER_BYTES
#error "serial RX buffer must be 256 bytes (-DSERIAL_RX_BUFFER_SIZE=256, as firmware/Makefile sets); an Arduino-IDE build gets 64 and overruns at 1 Mbaud"
#endif

#endif
