// rehab-hil device firmware for the Arduino Uno (protocol v1, docs/protocol.md).
//
// Structure: the Timer2 interrupt (1 kHz, io.cpp) runs every safety check and takes the
// sample snapshot, so a trip switches the PWM off within 1 ms even while loop() is busy
// sending. loop() reads the serial port, applies commands on arrival and sends the frames the
// interrupt queued. The AVR hardware watchdog (60 ms) resets the board if loop() ever stalls.
#include <Arduino.h>
#include <avr/wdt.h>
#include <util/atomic.h>
#include "io.h"
#include "protocol.h"
#include "rx_buffer_check.h"

#define FW_MAJOR 1
#define FW_MINOR 1
#define FW_PATCH 0
// The encoder is a property of the rig, not of the build: by default the firmware adopts the
// counts per revolution CONFIGURE carries and reports it in HELLO (0 until the first one).
// `make ENCODER_COUNTS_PER_REV=N` pins a build to one encoder: HELLO reports N from boot and a
// CONFIGURE with another non-zero value is refused (ACK 2, BAD_CONFIG).
#ifndef ENCODER_COUNTS_PER_REV
#define ENCODER_COUNTS_PER_REV 0
#endif

// Status bits (SAMPLE.status).
enum : uint16_t {
  ST_STREAMING = 1 << 0, ST_PWM_ENABLED = 1 << 1, ST_FAULT_LATCHED = 1 << 2,
  ST_ESTOP_INPUT_ACTIVE = 1 << 3, ST_DUTY_CLAMPED = 1 << 4, ST_WATCHDOG_ARMED = 1 << 5,
};
// Fault bits (SAMPLE.faults, FAULT).
enum : uint16_t {
  F_WATCHDOG = 1 << 0, F_HEATING_TIME = 1 << 1, F_FORCE_LIMIT = 1 << 2, F_RANGE_OF_MOTION = 1 << 3,
  F_ESTOP_INPUT = 1 << 4, F_ESTOP_COMMAND = 1 << 5, F_HW_WATCHDOG_RESET = 1 << 6, F_BAD_CONFIG = 1 << 7,
};

struct Config {
  uint16_t divider;         // sample every `divider` ticks; 0 = not streaming
  uint16_t watchdog_ms;
  uint16_t max_duty;
  uint32_t max_heating_ms;
  uint16_t force_limit;     // A0 counts; 1023 = off
  int32_t enc_min, enc_max;
  uint8_t flags;            // bit0: e-stop input enabled; bit1: normally-closed loop (pin high = stop)
  uint8_t force_debounce;   // FORCE_LIMIT after this many consecutive ticks above the limit (0 = 1)
};
enum : uint8_t { FLAG_ESTOP_ENABLED = 1 << 0, FLAG_ESTOP_NC = 1 << 1 };

// Until the host configures it the device is inert: max_duty 0 clamps every command to 0.
static Config cfg = {0, 100, 0, 10000, 1023, INT32_MIN, INT32_MAX, 0, 1};

// State shared with the tick interrupt.
static volatile uint16_t faults = 0;          // latched
static volatile uint16_t faults_unreported = 0;
static volatile bool wd_armed = false;
static volatile uint16_t ms_since_cmd = 0;
static volatile uint32_t heating_ms = 0;
static volatile uint8_t force_ticks = 0;       // consecutive ticks with A0 above the limit
static volatile uint16_t duty[2] = {0, 0};    // applied
static volatile uint8_t direction = 0;
static volatile bool pwm_enabled = false;
static volatile uint16_t tick_phase = 0;  // base ticks since the last SAMPLE tick
static volatile uint32_t tick_count = 0;  // base ticks since boot

struct Snapshot {
  uint32_t time_us;
  int32_t enc;
  uint16_t adc0, adc1;
};
static volatile bool sample_due = false;
static volatile Snapshot snap;
static uint32_t sample_index = 0;

static bool configured = false;        // a valid CONFIGURE arrived since boot
static bool duty_clamped = false;
static uint16_t cmd_seq_echo = 0;
static uint16_t tx_seq = 0;
static uint8_t reset_cause = 0;
static uint16_t encoder_cpr = ENCODER_COUNTS_PER_REV;  // adopted from CONFIGURE (0: not told yet)
static proto::Receiver rx;

// MCUSR holds why the chip reset; it must be read and cleared, and the watchdog disabled,
// before anything else: after a watchdog reset the WDT stays enabled at its shortest period.
// Under the Uno's bootloader MCUSR is always 0 here: optiboot (4.4 in Debian's arduino-core-avr)
// reads it into r24, clears it and overwrites r24 before jumping to the sketch, handing nothing
// over. So a hang is also recorded by the watchdog itself: it runs in interrupt-then-reset mode,
// its interrupt (first time-out) cuts the PWM and leaves hang_marker in SRAM, which every reset
// but power-on keeps; the second time-out resets the chip (WDIE is cleared by hardware at the
// first, so the reset comes even if interrupts stay disabled).
uint8_t mcusr_at_boot __attribute__((section(".noinit")));
static const uint32_t HANG_MAGIC = 0x57A7D06Eul;  // 32 bits: random SRAM after power-on matches 1 in 4e9
volatile uint32_t hang_marker __attribute__((section(".noinit")));
void early_init() __attribute__((naked, used, section(".init3")));
void early_init() {
  mcusr_at_boot = MCUSR;
  MCUSR = 0;
  wdt_disable();
}

ISR(WDT_vect) {
  io::pwm_all_off();  // a hung loop() loses the PWM now, the reset follows one period later
  hang_marker = HANG_MAGIC;
}

// Everything off; called with interrupts disabled or from the tick interrupt.
static void outputs_off() {
  io::pwm_all_off();
  duty[0] = duty[1] = 0;
  pwm_enabled = false;
  heating_ms = 0;
}

static void latch(uint16_t bits) {
  uint16_t fresh = bits & (uint16_t)~faults;
  faults |= bits;
  faults_unreported |= fresh;
  outputs_off();
}

// The e-stop input with the configured wiring: a normally-closed loop holds D4 low through the
// switch, so a pressed button or a broken wire lets the pull-up take it high (both a stop); a
// normally-open button pulls it low when pressed (a broken wire then reads "released").
static bool estop_active() {
  bool high = io::estop_pin_high();
  return (cfg.flags & FLAG_ESTOP_NC) ? high : !high;
}

// Causes that are still present (CLEAR refuses to clear these).
static uint16_t present_causes() {
  uint16_t c = 0;
  if (io::adc_value[0] > cfg.force_limit) c |= F_FORCE_LIMIT;
  int32_t e = io::encoder_count();
  if (e < cfg.enc_min || e > cfg.enc_max) c |= F_RANGE_OF_MOTION;
  if ((cfg.flags & FLAG_ESTOP_ENABLED) && estop_active()) c |= F_ESTOP_INPUT;
  return c;
}

// 1 kHz, interrupts disabled: safety first, then the sample snapshot.
void io::on_tick() {
  uint16_t trip = present_causes();
  // Force: only N consecutive ticks above the limit trip (a one-tick ADC spike from the PWM
  // stage's switching noise does not; a real overload lasts far longer than a few ms).
  if (trip & F_FORCE_LIMIT) {
    if (force_ticks < 0xFF) ++force_ticks;
    if (force_ticks < cfg.force_debounce) trip &= (uint16_t)~F_FORCE_LIMIT;
  } else {
    force_ticks = 0;
  }
  if (wd_armed) {
    if (ms_since_cmd < 0xFFFF) ++ms_since_cmd;
    if (ms_since_cmd >= cfg.watchdog_ms) {
      trip |= F_WATCHDOG;
      wd_armed = false;  // re-armed by the next COMMAND
    }
  }
  if (pwm_enabled && (duty[0] || duty[1])) {
    ++heating_ms;
    if (heating_ms >= cfg.max_heating_ms) trip |= F_HEATING_TIME;
  } else {
    heating_ms = 0;
  }
  trip &= (uint16_t)~faults;  // a latched cause is not re-latched every tick (keeps this ISR short)
  if (trip) latch(trip);

  ++tick_count;
  // A SAMPLE every k-th tick (a counter, not a 32-bit modulo: this ISR must stay short,
  // or encoder edges closer than its run time are lost).
  if (cfg.divider) {
    if (++tick_phase >= cfg.divider) {
      tick_phase = 0;
      // The tick's time: the tick count (Timer2 runs off the crystal, exactly 1 ms), not micros(),
      // which reads Timer0 with 4 us resolution plus this interrupt's entry latency.
      snap.time_us = tick_count * 1000ul;
      snap.enc = io::encoder_count();
      snap.adc0 = io::adc_value[0];
      snap.adc1 = io::adc_value[1];
      sample_due = true;  // an unsent previous sample is overwritten (the index shows the gap)
    }
  }
  io::adc_start_pair();
}

static void send(uint8_t type, const uint8_t *payload, uint8_t len) {
  uint8_t out[proto::MAX_ENCODED + 1];
  uint8_t n = proto::encode_frame(type, tx_seq++, payload, len, out);
  Serial.write(out, n);
}

static void send_ack(uint8_t type, uint16_t seq, uint8_t result) {
  uint8_t p[PROTO_LEN_ACK] = {type, (uint8_t)seq, (uint8_t)(seq >> 8), result};
  send(proto::ACK, p, sizeof p);
}

static void send_hello() {
  uint8_t p[proto::LEN_HELLO];
  p[0] = proto::VERSION; p[1] = FW_MAJOR; p[2] = FW_MINOR; p[3] = FW_PATCH;
  p[4] = 2; p[5] = 2;
  proto::put_u16(p + 6, encoder_cpr);
  proto::put_u16(p + 8, 5000);
  p[10] = 10;
  proto::put_u16(p + 11, 1000);
  p[13] = reset_cause;
  send(proto::HELLO, p, sizeof p);
}

static void handle_configure(uint16_t seq, const uint8_t *p) {
  uint16_t rate = proto::get_u16(p);
  Config c;
  c.watchdog_ms = proto::get_u16(p + 2);
  c.max_duty = proto::get_u16(p + 4);
  c.max_heating_ms = proto::get_u32(p + 6);
  c.force_limit = proto::get_u16(p + 10);
  c.enc_min = (int32_t)proto::get_u32(p + 12);
  c.enc_max = (int32_t)proto::get_u32(p + 16);
  c.flags = p[20];
  c.force_debounce = p[21];
  uint16_t cpr = proto::get_u16(p + 22);  // 0: keep the current value
  bool ok = c.watchdog_ms > 0 && c.max_duty <= io::DUTY_FULL && c.max_heating_ms > 0 && c.force_limit <= 1023 &&
            c.enc_min < c.enc_max && (cpr == 0 || cpr >= 4) &&
            (ENCODER_COUNTS_PER_REV == 0 || cpr == 0 || cpr == ENCODER_COUNTS_PER_REV);
  if (!ok) {
    ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { latch(F_BAD_CONFIG); }
    send_ack(proto::CONFIGURE, seq, 2);
    return;
  }
  // Supported rates are 1000/k Hz: k = max(1, (1000 + rate/2) / rate), the nearest one.
  if (rate) {
    uint32_t k = (1000ul + rate / 2) / rate;
    c.divider = k ? (uint16_t)k : 1;
  } else {
    c.divider = 0;
  }
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    cfg = c;
    outputs_off();           // a new configuration starts from rest
    wd_armed = false;        // armed again by the first COMMAND
    ms_since_cmd = 0;
    tick_phase = 0;          // first SAMPLE k ticks after the CONFIGURE
    sample_due = false;
  }
  configured = true;
  duty_clamped = false;
  if (cpr) encoder_cpr = cpr;
  send_ack(proto::CONFIGURE, seq, 0);
}

static void handle_command(uint16_t seq, const uint8_t *p) {
  uint16_t d[2] = {proto::get_u16(p), proto::get_u16(p + 2)};
  uint8_t dir = p[4] & 3;
  bool enable = p[5] != 0;
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    if (!configured) return;  // ignored before the first accepted CONFIGURE
    ms_since_cmd = 0;  // any valid COMMAND feeds and arms the watchdog, even one refused below
    wd_armed = true;
    if (faults) return;  // latched: PWM stays off, command not applied
    bool clamped = false;
    for (uint8_t k = 0; k < 2; ++k) {
      if (d[k] > cfg.max_duty) { d[k] = cfg.max_duty; clamped = true; }
      if (!enable) d[k] = 0;
    }
    if (enable) {  // a disabling COMMAND leaves the direction pins as they were
      io::direction_set(dir);
      direction = dir;
    }
    io::pwm_set(0, d[0]);
    io::pwm_set(1, d[1]);
    duty[0] = d[0]; duty[1] = d[1];
    pwm_enabled = enable;
    duty_clamped = clamped;
    cmd_seq_echo = seq;
  }
}

static void handle_clear(uint16_t seq) {
  uint8_t result;
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    faults &= present_causes();
    faults_unreported &= faults;
    result = faults ? 1 : 0;
  }
  send_ack(proto::CLEAR, seq, result);
}

static void handle_packet(const uint8_t *pkt, uint8_t n) {
  uint8_t type = pkt[1];
  uint16_t seq = proto::get_u16(pkt + 2);
  const uint8_t *p = pkt + proto::HEADER;
  uint8_t len = n - proto::OVERHEAD;
  if (proto_host_payload_len(type) != (int)len) {  // unknown type or wrong payload length
    rx.count_bad();
    return;
  }
  switch (type) {
    case proto::HELLO_REQ:
      send_hello();
      return;
    case proto::CONFIGURE:
      handle_configure(seq, p);
      return;
    case proto::COMMAND:
      handle_command(seq, p);
      return;
    case proto::HEARTBEAT_REQ: {
      uint8_t q[PROTO_LEN_HEARTBEAT];
      proto::put_u32(q, millis());
      send(proto::HEARTBEAT, q, sizeof q);
      return;
    }
    case proto::ESTOP:
      ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { latch(F_ESTOP_COMMAND); }
      send_ack(proto::ESTOP, seq, 0);
      return;
    case proto::CLEAR:
      handle_clear(seq);
      return;
    case proto::SET_ENCODER:
      io::encoder_set((int32_t)proto::get_u32(p));  // the range check sees it from the next tick
      send_ack(proto::SET_ENCODER, seq, 0);
      return;
    default:
      break;
  }
  rx.count_bad();  // a host type the switch does not handle
}

static void send_fault(uint16_t fresh, uint16_t all) {
  uint8_t p[PROTO_LEN_FAULT];
  proto::put_u16(p, fresh);
  proto::put_u16(p + 2, all);
  send(proto::FAULT, p, sizeof p);
}

static void send_sample() {
  Snapshot s;
  uint16_t d0, d1, st, f, fresh;
  uint8_t dir;
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    // Trips not reported yet go out first, so a FAULT never arrives after a SAMPLE showing it.
    fresh = faults_unreported;
    faults_unreported = 0;
    s.time_us = snap.time_us; s.enc = snap.enc; s.adc0 = snap.adc0; s.adc1 = snap.adc1;
    sample_due = false;
    d0 = duty[0]; d1 = duty[1]; dir = direction; f = faults;
    st = (cfg.divider ? ST_STREAMING : 0) | (pwm_enabled ? ST_PWM_ENABLED : 0) |
         (faults ? ST_FAULT_LATCHED : 0) | (estop_active() ? ST_ESTOP_INPUT_ACTIVE : 0) |
         (duty_clamped ? ST_DUTY_CLAMPED : 0) | (wd_armed ? ST_WATCHDOG_ARMED : 0);
  }
  if (fresh) send_fault(fresh, f);
  uint8_t p[proto::LEN_SAMPLE];
  proto::put_u32(p, s.time_us);
  proto::put_u32(p + 4, sample_index++);
  proto::put_u32(p + 8, (uint32_t)s.enc);
  proto::put_u16(p + 12, s.adc0);
  proto::put_u16(p + 14, s.adc1);
  proto::put_u16(p + 16, d0);
  proto::put_u16(p + 18, d1);
  p[20] = dir;
  proto::put_u16(p + 21, st);
  proto::put_u16(p + 23, f);
  proto::put_u16(p + 25, cmd_seq_echo);
  proto::put_u16(p + 27, rx.bad_frames());
  send(proto::SAMPLE, p, sizeof p);
}

void setup() {
  uint8_t m = mcusr_at_boot;
  bool hung = hang_marker == HANG_MAGIC && !(m & _BV(PORF));  // SRAM is random after power-on
  hang_marker = 0;
  if (hung) m |= _BV(WDRF);  // our watchdog reset us (MCUSR itself was cleared by the bootloader)
  reset_cause = ((m & _BV(PORF)) ? 1 : 0) | ((m & _BV(EXTRF)) ? 2 : 0) | ((m & _BV(BORF)) ? 4 : 0) |
                ((m & _BV(WDRF)) ? 8 : 0);
  io::begin();
  Serial.begin(1000000);
  if (m & _BV(WDRF)) {
    faults = F_HW_WATCHDOG_RESET;  // PWM is already off (io::begin); reported once the host asks
    faults_unreported = F_HW_WATCHDOG_RESET;
  }
  // A lone delimiter first: a reset can cut a frame short, and without it the host's decoder
  // would merge that partial frame with this HELLO and drop both.
  Serial.write((uint8_t)0);
  send_hello();  // unsolicited, once per boot: reset_cause tells the host why we booted
  wdt_enable(WDTO_60MS);
  WDTCSR |= _BV(WDIE);  // interrupt first, then reset (WDIE needs no timed sequence)
}

void loop() {
  wdt_reset();  // WDIE stays set until a time-out
  // Bounded so a flood cannot starve the samples; read() returns -1 when empty (one call per
  // byte instead of two: at 1 Mbaud a byte arrives every 160 CPU cycles).
  for (uint8_t i = 0; i < 64; ++i) {
    int c = Serial.read();
    if (c < 0) break;
    if (rx.feed((uint8_t)c)) handle_packet(rx.packet(), rx.length());
  }
  uint16_t fresh;
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    fresh = faults_unreported;
    faults_unreported = 0;
  }
  if (fresh) send_fault(fresh, faults);
  if (sample_due) send_sample();
#ifdef FW_TEST_HANG
  // Test builds only (firmware/Makefile TEST_HOOKS=1): the e-stop pin held low with the e-stop
  // input disabled makes the firmware hang, to prove the hardware watchdog resets the board.
  if (!(cfg.flags & FLAG_ESTOP_ENABLED) && !io::estop_pin_high() && cfg.divider) { for (;;) {} }
#endif
}
