#include "io.h"
#include <Arduino.h>
#include <avr/interrupt.h>
#include <util/atomic.h>

namespace io {

volatile uint16_t adc_value[2];
static volatile int32_t enc_count = 0;
static volatile uint8_t enc_state = 0;
static volatile uint8_t adc_channel = 0xFF;  // 0xFF = idle

// x4 quadrature decoding: index = previous state << 2 | new state, state = A << 1 | B.
// Forward (A leads B) is 00 -> 10 -> 11 -> 01 -> 00; a double step (both lines changed, an
// edge was missed) counts 0.
static const int8_t QUAD_TABLE[16] = {
    0, -1, +1, 0,   // from 00: to 01 back, to 10 fwd
    +1, 0, 0, -1,   // from 01: to 00 fwd, to 11 back
    -1, 0, 0, +1,   // from 10: to 00 back, to 11 fwd
    0, +1, -1, 0,   // from 11: to 01 fwd, to 10 back
};

static inline uint8_t read_ab() {
  uint8_t pind = PIND;
  return (uint8_t)(((pind >> 1) & 0x02) | ((pind >> 3) & 0x01));  // A = PD2, B = PD3
}

static inline void encoder_update() {
  uint8_t s = read_ab();
  enc_count += QUAD_TABLE[(enc_state << 2) | s];
  enc_state = s;
}

void begin() {
  // Direction pins D8 (PB0), D7 (PD7): outputs, low.
  pinMode(8, OUTPUT); digitalWrite(8, LOW);
  pinMode(7, OUTPUT); digitalWrite(7, LOW);
  // PWM pins D9 (PB1/OC1A), D10 (PB2/OC1B): outputs, low, disconnected from the timer.
  pinMode(9, OUTPUT); digitalWrite(9, LOW);
  pinMode(10, OUTPUT); digitalWrite(10, LOW);
  // Timer1: fast PWM, TOP = ICR1 (mode 14), no prescaler -> 20 kHz, 800 steps.
  TCCR1A = _BV(WGM11);
  TCCR1B = _BV(WGM13) | _BV(WGM12) | _BV(CS10);
  ICR1 = PWM_TOP;
  OCR1A = 0;
  OCR1B = 0;
  // Encoder: D2/D3 inputs with pull-ups, interrupt on any change of either line.
  pinMode(2, INPUT_PULLUP);
  pinMode(3, INPUT_PULLUP);
  enc_state = read_ab();
  EICRA = _BV(ISC00) | _BV(ISC10);
  EIFR = _BV(INTF0) | _BV(INTF1);
  EIMSK = _BV(INT0) | _BV(INT1);
  // E-stop input D4, active low.
  pinMode(4, INPUT_PULLUP);
  // ADC: AVcc reference, prescaler 128 (125 kHz, 104 us per conversion), interrupt on completion.
  ADMUX = _BV(REFS0);
  ADCSRA = _BV(ADEN) | _BV(ADIE) | _BV(ADPS2) | _BV(ADPS1) | _BV(ADPS0);
  // Timer2: CTC, prescaler 64, OCR2A = 249 -> 16 MHz / 64 / 250 = 1 kHz tick.
  TCCR2A = _BV(WGM21);
  TCCR2B = _BV(CS22);
  OCR2A = 249;
  TCNT2 = 0;
  TIMSK2 = _BV(OCIE2A);
}

// One output: 0 and 100 % are plain port levels with the compare output disconnected (fast PWM
// would otherwise leave a one-clock spike at OCR = 0); in between the timer drives the pin
// with duty = (OCR + 1) / (TOP + 1).
void pwm_set(uint8_t ch, uint16_t duty) {
  uint8_t com = ch == 0 ? _BV(COM1A1) : _BV(COM1B1);
  uint8_t pin = ch == 0 ? _BV(PB1) : _BV(PB2);
  // steps = round(duty * 800 / 10000) = round(duty * 0.08), as a multiply by 5243 / 2^16 (exact
  // for every duty 0..10000; a 32-bit division costs ~40 us on the AVR, per channel per COMMAND).
  static_assert(PWM_TOP + 1 == 800 && DUTY_FULL == 10000, "the reciprocal below assumes 800 steps");
  uint16_t steps = (uint16_t)(((uint32_t)duty * 5243u + 32768u) >> 16);  // 0..800
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    if (steps == 0) {
      TCCR1A &= (uint8_t)~com;
      PORTB &= (uint8_t)~pin;
    } else if (steps > PWM_TOP) {
      TCCR1A &= (uint8_t)~com;
      PORTB |= pin;
    } else {
      if (ch == 0) OCR1A = (uint16_t)(steps - 1); else OCR1B = (uint16_t)(steps - 1);
      TCCR1A |= com;
    }
  }
}

void pwm_all_off() {
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    TCCR1A &= (uint8_t)~(_BV(COM1A1) | _BV(COM1A0) | _BV(COM1B1) | _BV(COM1B0));
    PORTB &= (uint8_t)~(_BV(PB1) | _BV(PB2));
  }
}

void direction_set(uint8_t bits) {
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) {
    if (bits & 1) PORTB |= _BV(PB0); else PORTB &= (uint8_t)~_BV(PB0);
    if (bits & 2) PORTD |= _BV(PD7); else PORTD &= (uint8_t)~_BV(PD7);
  }
}

int32_t encoder_count() {
  int32_t c;
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { c = enc_count; }
  return c;
}

void encoder_set(int32_t count) {
  ATOMIC_BLOCK(ATOMIC_RESTORESTATE) { enc_count = count; }
}

bool estop_pin_high() { return (PIND & _BV(PD4)) != 0; }

void adc_start_pair() {
  if (adc_channel != 0xFF) return;  // previous pair still converting
  adc_channel = 0;
  ADMUX = _BV(REFS0) | 0;
  ADCSRA |= _BV(ADSC);
}

}  // namespace io

ISR(INT0_vect) { io::encoder_update(); }
ISR(INT1_vect) { io::encoder_update(); }

ISR(ADC_vect) {
  uint16_t v = ADC;
  uint8_t ch = io::adc_channel;
  if (ch < 2) io::adc_value[ch] = v;
  if (ch == 0) {
    io::adc_channel = 1;
    ADMUX = _BV(REFS0) | 1;
    ADCSRA |= _BV(ADSC);
  } else {
    io::adc_channel = 0xFF;
  }
}

// Interruptible (ISR_NOBLOCK): the safety checks take longer than two bytes at 1 Mbaud, and the
// 328P holds only two received bytes; the UART receive interrupt must be able to preempt them.
ISR(TIMER2_COMPA_vect, ISR_NOBLOCK) { io::on_tick(); }
