// Rig I/O on the Arduino Uno: PWM (Timer1), direction pins, quadrature encoder (INT0/INT1),
// ADC A0/A1 (interrupt driven), e-stop input, and the Timer2 sample tick.
#pragma once
#include <stdint.h>

namespace io {

const uint16_t DUTY_FULL = 10000;       // protocol duty units for 100 %
const uint16_t PWM_TOP = 799;           // Timer1 fast PWM, ICR1 = TOP: 16 MHz / 800 = 20 kHz

void begin();                           // configure every peripheral; PWM off
void pwm_set(uint8_t ch, uint16_t duty);  // duty in protocol units (0..10000)
void pwm_all_off();                     // both PWM outputs low at once (safe state)
void direction_set(uint8_t bits);       // bit k = channel k reversed (D8 ch0, D7 ch1)

int32_t encoder_count();                // atomic read of the x4 count
void encoder_set(int32_t count);        // atomic write (homing); edges keep counting from it
bool estop_pin_high();                  // D4 level (INPUT_PULLUP: high when open)

// Written by the ADC interrupt: the last conversions of A0 and A1 (0..1023).
extern volatile uint16_t adc_value[2];
// Starts one A0-then-A1 conversion pair; called from the tick interrupt (interrupt-driven:
// analogRead would block the CPU ~224 us per tick).
void adc_start_pair();
// Called every 1 ms from the Timer2 compare interrupt (defined in the sketch).
void on_tick();

}  // namespace io
