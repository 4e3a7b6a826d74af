/*
 * avr_harness: runs the rehab-hil firmware ELF in simavr (1.6) as an ATmega328P at 16 MHz,
 * exposes UART0 on its own pseudo-terminal, and exchanges rig I/O with a driver over a pipe.
 *
 * stdout: line 1 is the pty path; every later line is a reply (see README.md). simavr's log
 * and stray printf()s go to stderr (fd 1 is redirected there; replies use a dup of the original).
 *
 * Usage: avr_harness [-f] [-k] [-d DELAY_US] [-l LOCKSTEP_US] [-e EDGE_US] [-b BOOT.hex] [-r] [-u] [-v] firmware.elf
 *   -f  free-running: do not throttle simulated time to the wall clock
 *   -b  load a bootloader (Intel hex, e.g. optiboot at 0x7E00) with the sketch and start there
 *       (BOOTRST fuse programmed, as on an Uno)
 *   -r  reset on port open (the Uno's DTR auto-reset): an external reset each time the host opens the pty
 *   -u  real UART receive: host bytes enter the 328P one per byte time (10 bits at the baud rate the
 *       firmware set in UBRR0/U2X0) into its 2-byte receive buffer; a byte completing while 2 are
 *       unread is lost (data overrun, counted in rx_dropped), instead of simavr's 64-byte FIFO
 *   -l  lockstep: stop every LOCKSTEP_US of simulated time, print a T line, wait for G
 *   -k  host-paced (virtual time, with -f): simulated time stops after each SAMPLE, ACK or HELLO the AVR
 *       sends and runs again when a whole frame from the host has arrived, so device time advances
 *       only as the host allows (the Python device's lockstep clock), whatever the machine's load
 *   -d  with -u: each burst of host bytes reaches the UART after 0..D us of simulated time (a fixed
 *       pseudo-random sequence): the host's reaction time, at any phase of the tick, in virtual time
 *   -e  simulated time between two generated encoder edges (default 50 us = 20,000 counts/s;
 *       closer edges can fall within one interrupt latency and be lost, see README.md)
 *   -v  pass simavr's warnings to stderr
 */
#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include <avr_adc.h>
#include <avr_extint.h>
#include <avr_ioport.h>
#include <avr_uart.h>
#include <sim_avr.h>
#include <sim_elf.h>
#include <sim_hex.h>
#include <sim_irq.h>

#include "protocol_ids.h" /* frame types and payload lengths: the firmware's own (firmware/rehab_fw) */

#define F_CPU 16000000UL
#define CYC_PER_US (F_CPU / 1000000UL)
#define SLICE_US 200         /* simulated time run between two I/O polls (50 us cost ~35 % more CPU) */
#define MAX_LAG_US 20000     /* throttled: never let the simulation fall further behind */

/* ATmega328P data-space addresses of the registers the harness reads. */
#define R_PINB 0x23
#define R_PORTB 0x25
#define R_PIND 0x29
#define R_PORTD 0x2B
#define R_TCCR1A 0x80
#define R_TCCR1B 0x81
#define R_ICR1L 0x86
#define R_OCR1AL 0x88
#define R_OCR1BL 0x8A
#define R_UCSR0B 0xC1
#define R_MCUSR 0x54
#define R_UCSR0A 0xC0
#define R_UBRR0L 0xC4
#define R_UBRR0H 0xC5
#define R_UDR0 0xC6
#define RXEN0_BIT 4
#define U2X0_BIT 1

static avr_t *avr;
static int reply_fd = -1, pty_master = -1, pty_slave = -1;
static int verbose = 0, free_running = 0, reset_on_open = 0, uart_real = 0, host_paced = 0;
static int host_open = 0;
static const char *boot_hex = NULL;
static uint32_t boot_pc = 0;
static avr_uart_t *uart0;                     /* for its receive FIFO's fill level (-u) */
static uint64_t rx_overrun = 0, rx_fed = 0;
static uint64_t rx_frames_hit = 0;            /* frames, as the firmware delimits them, that lost a byte */
static int frame_hit = 0;
static uint32_t lockstep_us = 0, edge_us = 50;
static avr_irq_t *uart_in_irq, *pin_irq[8], *adc_irq;
static volatile int xoff = 0;
static volatile sig_atomic_t stop = 0;

/* -k: the frame the AVR is sending (its COBS-encoded type byte sits at offset 2, since the packet's
 * version and type bytes are never 0), the host frame being received, and the host frames the
 * firmware has not answered yet. */
static uint8_t dev_frame[80];
static size_t dev_frame_len = 0;
static uint8_t host_frame[80];
static size_t host_frame_len = 0;
/* Answers owed, by kind: a SAMPLE (to COMMANDs), a HELLO (HELLO_REQ), an ACK (CONFIGURE, ESTOP,
 * CLEAR, SET_ENCODER), a HEARTBEAT (HEARTBEAT). Counted per kind, so an answer the harness did not
 * count (a request the bootloader ate, bytes sent before the sketch booted) cannot stand for another. */
enum { OWE_SAMPLE, OWE_HELLO, OWE_ACK, OWE_HEARTBEAT, OWE_KINDS };
static uint64_t owed[OWE_KINDS];
static int boot_hello = 1;             /* the HELLO the firmware sends at boot answers nobody */
static uint32_t host_delay_us = 0, last_sample_time_us = 0;  /* -d */
static int gate_closed = 0;            /* simulated time stopped until the next host frame */

static uint8_t rx_buf[4096];          /* pty -> AVR, waiting for room in the UART fifo */
static size_t rx_len = 0;
static uint8_t tx_buf[8192];          /* AVR -> pty */
static size_t tx_len = 0;
static uint64_t tx_dropped = 0, rx_dropped = 0;

static int32_t enc_pos = 0, enc_target = 0;   /* x4 counts driven on D2/D3 */
static uint32_t adc_mv[8];                    /* the level each ADC input is held at */
static int pulse_ch = -1;                     /* an ADC pulse in progress (P): its channel */
static uint8_t estop_level = 1;               /* D4, idle high (pull-up) */
static uint32_t resets = 0;
static struct timespec wall0;
static int64_t sim_origin_us = 0;  /* simulated time that corresponds to wall0 */

static void logger(avr_t *a, const int level, const char *fmt, va_list ap) {
    (void)a;
    if (verbose && level <= LOG_WARNING) vfprintf(stderr, fmt, ap);
}

/* A HELLO answers a HELLO_REQ, a SAMPLE a COMMAND while streaming, a HEARTBEAT a HEARTBEAT_REQ and an
 * ACK a CONFIGURE, CLEAR, SET_ENCODER or ESTOP. */

static size_t cobs_decode(const uint8_t *enc, size_t n, uint8_t *dec, size_t cap);

static int nothing_owed(void) {
    for (int k = 0; k < OWE_KINDS; k++) if (owed[k]) return 0;
    return 1;
}

/* -k: simulated time stops when the firmware has answered every host frame, until the host speaks
 * again. A SAMPLE answers the COMMANDs before it (the firmware streams on its own timer: one sent
 * right after the previous SAMPLE is applied by the next tick; one that lands later, or is lost to a
 * receive overrun, is not echoed, and the host sends on, as its loop does every period). A COMMAND
 * while not streaming gets no answer: time then runs until a SAMPLE comes. The HELLO sent at boot
 * starts afresh: what was sent before belonged to the bootloader or to the reset. */
static void on_frame_sent(const uint8_t *enc, size_t n) {
    uint8_t dec[80];
    size_t len = cobs_decode(enc, n, dec, sizeof dec);
    if (len < 6) return;
    switch (dec[1]) {
        case PROTO_T_SAMPLE:
            if (len < 8) return;
            last_sample_time_us = (uint32_t)(dec[4] | (dec[5] << 8) | (dec[6] << 16) | ((uint32_t)dec[7] << 24));
            owed[OWE_SAMPLE] = 0;
            break;
        case PROTO_T_HELLO:
            if (boot_hello) { boot_hello = 0; memset(owed, 0, sizeof owed); }
            else if (owed[OWE_HELLO]) owed[OWE_HELLO]--;
            break;
        case PROTO_T_ACK: if (owed[OWE_ACK]) owed[OWE_ACK]--; break;
        case PROTO_T_HEARTBEAT: if (owed[OWE_HEARTBEAT]) owed[OWE_HEARTBEAT]--; break;
        default: return;
    }
    if (nothing_owed()) gate_closed = 1;
}

/* CRC-16/CCITT-FALSE, as the protocol (and the firmware) computes it. */
static uint16_t crc16(const uint8_t *d, size_t n) {
    uint16_t crc = 0xFFFF;
    for (size_t i = 0; i < n; i++) {
        crc ^= (uint16_t)d[i] << 8;
        for (int b = 0; b < 8; b++) crc = (crc & 0x8000) ? (uint16_t)((crc << 1) ^ 0x1021) : (uint16_t)(crc << 1);
    }
    return crc;
}

/* COBS-decodes one frame (without its 0x00); returns the packet's length, 0 if malformed. */
static size_t cobs_decode(const uint8_t *enc, size_t n, uint8_t *dec, size_t cap) {
    size_t out = 0, i = 0;
    while (i < n) {
        uint8_t code = enc[i++];
        if (!code) return 0;
        for (uint8_t k = 1; k < code; k++) { if (i >= n || out >= cap) return 0; dec[out++] = enc[i++]; }
        if (code < 0xFF && i < n) { if (out >= cap) return 0; dec[out++] = 0; }
    }
    return out;
}

/* The firmware's own check (protocol_ids.h): a frame it counts as bad is answered by nothing. */
static int host_payload_ok(uint8_t type, size_t len) {
    int want = proto_host_payload_len(type);
    return want >= 0 && (size_t)want == len;
}

/* One whole host frame: a packet the firmware accepts is owed an answer; one it drops (bad CRC,
 * version, type or payload length) is owed nothing. Were a dropped frame owed a SAMPLE, time would
 * run to one more SAMPLE than the host's COMMANDs asked for whenever the harness read it apart
 * from the COMMAND after it (as it does when the machine is busy), and every later SAMPLE would
 * reach the host one COMMAND late. */
static void on_host_frame(const uint8_t *enc, size_t n) {
    uint8_t dec[80];
    size_t out = cobs_decode(enc, n, dec, sizeof dec);
    if (out < 6 || dec[0] != PROTO_VERSION) return;
    if (crc16(dec, out - 2) != (uint16_t)(dec[out - 2] | (dec[out - 1] << 8))) return;
    if (!host_payload_ok(dec[1], out - 6)) return;
    switch (dec[1]) {
        case PROTO_T_HELLO_REQ: owed[OWE_HELLO]++; break;
        case PROTO_T_CONFIGURE: case PROTO_T_ESTOP: case PROTO_T_CLEAR: case PROTO_T_SET_ENCODER: owed[OWE_ACK]++; break;
        case PROTO_T_COMMAND: owed[OWE_SAMPLE] = 1; break;
        case PROTO_T_HEARTBEAT_REQ: owed[OWE_HEARTBEAT]++; break;
        default: break;
    }
}
static void on_host_bytes(const uint8_t *d, size_t n) {
    for (size_t i = 0; i < n; i++) {
        if (d[i]) { if (host_frame_len < sizeof host_frame) host_frame[host_frame_len++] = d[i]; else host_frame_len = sizeof host_frame; continue; }
        if (host_frame_len && host_frame_len < sizeof host_frame) on_host_frame(host_frame, host_frame_len);
        host_frame_len = 0;
    }
}

static void on_uart_out(avr_irq_t *irq, uint32_t value, void *param) {
    (void)irq; (void)param;
    if (tx_len < sizeof tx_buf) tx_buf[tx_len++] = (uint8_t)value;
    else tx_dropped++;
    if (!host_paced) return;
    if (value) {
        if (dev_frame_len < sizeof dev_frame) dev_frame[dev_frame_len++] = (uint8_t)value;
        return;
    }
    if (dev_frame_len && dev_frame_len < sizeof dev_frame) on_frame_sent(dev_frame, dev_frame_len);
    dev_frame_len = 0;
}
static void on_xoff(avr_irq_t *irq, uint32_t value, void *param) { (void)irq; (void)param; xoff = value != 0; }
static void on_xon(avr_irq_t *irq, uint32_t value, void *param) { (void)irq; (void)param; if (value) xoff = 0; }

static uint64_t sim_us(void) { return avr->cycle / CYC_PER_US; }
static uint64_t wall_us(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (uint64_t)(t.tv_sec - wall0.tv_sec) * 1000000u + (uint64_t)((t.tv_nsec - wall0.tv_nsec) / 1000);
}

/* The encoder lines and the e-stop pin are inputs the harness drives. simavr re-applies an
 * input's pull-up on every PORTD write, overwriting what we drove (issue 3 in the notes), so
 * they are declared "external" and their external level is kept equal to the driven level. */
static uint8_t quad_ab(int32_t count) {
    static const uint8_t seq[4] = {0x0, 0x2, 0x3, 0x1}; /* A<<1|B: 00 -> 10 -> 11 -> 01 (A leads) */
    return seq[count & 3];
}
static void drive_inputs(void) {
    uint8_t ab = quad_ab(enc_pos);
    uint8_t a = (ab >> 1) & 1, b = ab & 1;
    uint8_t value = (uint8_t)((a << 2) | (b << 3) | (estop_level << 4));
    avr_ioport_external_t ext = {.name = 'D', .mask = 0x1C, .value = value};
    avr_ioctl(avr, AVR_IOCTL_IOPORT_SET_EXTERNAL('D'), &ext);
    avr_raise_irq(pin_irq[2], a);
    avr_raise_irq(pin_irq[3], b);
    avr_raise_irq(pin_irq[4], estop_level);
}

/* One quadrature edge per edge_us towards the target count (x4: every edge is one count). */
static avr_cycle_count_t encoder_timer(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a; (void)param;
    if (enc_pos == enc_target) return 0;  /* idle: stop until the next target (encoder_kick) */
    enc_pos += enc_target > enc_pos ? 1 : -1;
    drive_inputs();
    return enc_pos == enc_target ? 0 : when + (avr_cycle_count_t)edge_us * CYC_PER_US;
}

/* The end of an ADC pulse (P): the input goes back to its held level. */
static avr_cycle_count_t pulse_end(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a; (void)when; (void)param;
    if (pulse_ch >= 0) avr_raise_irq(adc_irq + pulse_ch, adc_mv[pulse_ch]);
    pulse_ch = -1;
    return 0;
}

/* Starts the edge timer when the target moved (it does not run while the encoder is idle). */
static void encoder_kick(void) {
    if (enc_pos != enc_target && !avr_cycle_timer_status(avr, encoder_timer, NULL))
        avr_cycle_timer_register(avr, (avr_cycle_count_t)edge_us * CYC_PER_US, encoder_timer, NULL);
}

/* The three simavr 1.6 workarounds; re-applied after every reset (a reset restores the
 * extint default, which is how a reset is detected). */
static void apply_workarounds(void) {
    /* 1: INT0/INT1 held low would be re-polled every cycle (upstream bug #465). */
    avr_extint_set_strict_lvl_trig(avr, 0, 0);
    avr_extint_set_strict_lvl_trig(avr, 1, 0);
    /* 2: no sleeping on idle UART status reads, no console echo. */
    uint32_t flags = 0;
    avr_ioctl(avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
    flags &= ~(uint32_t)(AVR_UART_FLAG_POLL_SLEEP | AVR_UART_FLAG_STDIO);
    avr_ioctl(avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
    /* 3: externally driven pins (see drive_inputs). */
    drive_inputs();
    /* A reset also cancels every cycle timer and empties the UART fifo. */
    avr_cycle_timer_cancel(avr, encoder_timer, NULL);
    encoder_kick();
    xoff = 0;
    gate_closed = 0;  /* -k: a reset interrupts any frame and forgets what was owed */
    dev_frame_len = 0;
    memset(owed, 0, sizeof owed);
    host_frame_len = 0;
    boot_hello = 1;
}

/* PWM duty of one Timer1 channel from the registers (simavr 1.6 does not model the waveform):
 * with COM1x1 set the timer drives the pin, duty = (OCR + 1) / (TOP + 1) in fast PWM;
 * otherwise the pin is a plain port level. Returned in protocol duty units (0..10000). */
static unsigned pwm_duty(int ch) {
    uint8_t tccr1a = avr->data[R_TCCR1A], tccr1b = avr->data[R_TCCR1B];
    uint8_t com1 = ch == 0 ? (tccr1a & 0x80) : (tccr1a & 0x20);
    uint8_t pinbit = ch == 0 ? 0x02 : 0x04;
    if (!com1) return (avr->data[R_PORTB] & pinbit) ? 10000u : 0u;
    unsigned wgm = (tccr1a & 3) | ((tccr1b >> 1) & 0x0C);
    unsigned top;
    switch (wgm) {
        case 1: case 5: top = 0xFF; break;
        case 2: case 6: top = 0x1FF; break;
        case 3: case 7: top = 0x3FF; break;
        case 9: case 11: case 15: top = avr->data[R_OCR1AL] | (avr->data[R_OCR1AL + 1] << 8); break;
        default: top = avr->data[R_ICR1L] | (avr->data[R_ICR1L + 1] << 8); break;
    }
    uint16_t a = ch == 0 ? R_OCR1AL : R_OCR1BL;
    unsigned ocr = avr->data[a] | (avr->data[a + 1] << 8);
    if (ocr >= top) return 10000u;
    return (unsigned)(((uint64_t)(ocr + 1) * 10000u + (top + 1) / 2) / (top + 1));
}

/* -u: one received byte per byte time into the 328P's 2-byte buffer (see the usage). */
static avr_cycle_count_t uart_byte_cycles(void) {
    unsigned ubrr = avr->data[R_UBRR0L] | ((avr->data[R_UBRR0H] & 0x0F) << 8);
    unsigned per_bit = (avr->data[R_UCSR0A] & (1 << U2X0_BIT)) ? 8 : 16;
    /* 8N1 is 10 bit times a byte, but simavr 1.6 paces its receive-complete flag at 11 (it counts a
     * parity bit that 8N1 does not have): fed faster than simavr hands bytes to the firmware, every
     * frame longer than ~20 bytes would overrun in simulation only. So bytes come at simavr's pace
     * (91 kB/s at 1 Mbaud instead of 100 kB/s). */
    return (avr_cycle_count_t)11 * per_bit * (ubrr + 1);
}
static avr_cycle_count_t uart_feed(avr_t *a, avr_cycle_count_t when, void *param) {
    (void)a; (void)param;
    if (!rx_len || !(avr->data[R_UCSR0B] & (1 << RXEN0_BIT))) return 0;  /* idle: pump_pty restarts it */
    unsigned unread = (unsigned)(uart0->input.write - uart0->input.read) & (uart_fifo_fifo_size - 1);
    if (unread >= 2) { rx_overrun++; frame_hit = 1; }  /* DOR: the 328P holds 2 unread bytes, this one is lost */
    else {
        avr_raise_irq(uart_in_irq, rx_buf[0]);
        rx_fed++;
        /* a lost delimiter merges two frames into one: counted where the firmware's frame ends */
        if (rx_buf[0] == 0 && frame_hit) { rx_frames_hit++; frame_hit = 0; }
    }
    memmove(rx_buf, rx_buf + 1, --rx_len);
    return rx_len ? when + uart_byte_cycles() : 0;
}

/* -d: the host's reaction time, 0..host_delay_us of simulated time per burst of host bytes, drawn
 * from a hash of the device time of the firmware's last SAMPLE: in virtual time (-k) a reply lands at
 * any phase of the firmware's tick, and at the same phases on every run, however many requests the
 * host needed to connect. */
static avr_cycle_count_t host_delay_cycles(void) {
    if (!host_delay_us) return 0;
    uint32_t x = last_sample_time_us * 2654435761u + 0x9E3779B9u;
    x ^= x << 13;
    x ^= x >> 17;
    x ^= x << 5;
    return (avr_cycle_count_t)(x % (host_delay_us + 1)) * CYC_PER_US;
}

static void reply(const char *fmt, ...) {
    char line[256];
    va_list ap;
    va_start(ap, fmt);
    int n = vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    if (n <= 0) return;
    if (n >= (int)sizeof line) n = sizeof line - 1;
    const char *p = line;
    while (n > 0) {
        ssize_t w = write(reply_fd, p, (size_t)n);
        if (w < 0) { if (errno == EINTR) continue; stop = 1; return; }
        p += w; n -= (int)w;
    }
}

/* T sim_us duty0 duty1 dir enc_pos resets tx_dropped rx_dropped rx_frames_hit */
static void report_state(void) {
    uint8_t dir = (uint8_t)(((avr->data[R_PORTB] & 0x01) ? 1 : 0) | ((avr->data[R_PORTD] & 0x80) ? 2 : 0));
    reply("T %llu %u %u %u %ld %u %llu %llu %llu\n", (unsigned long long)sim_us(), pwm_duty(0), pwm_duty(1), dir,
          (long)enc_pos, resets, (unsigned long long)tx_dropped, (unsigned long long)(rx_dropped + rx_overrun),
          (unsigned long long)rx_frames_hit);
}

static void pump_pty(void) {
    /* AVR -> pty (non-blocking; with nobody reading, the kernel buffer fills and bytes drop). */
    if (tx_len) {
        ssize_t w = write(pty_master, tx_buf, tx_len);
        if (w > 0) { memmove(tx_buf, tx_buf + w, tx_len - (size_t)w); tx_len -= (size_t)w; }
        else if (w < 0 && errno == EAGAIN && tx_len > sizeof tx_buf / 2) { tx_dropped += tx_len; tx_len = 0; }
        else if (w < 0 && errno == EIO) { tx_dropped += tx_len; tx_len = 0; }  /* -r: nobody has the port open */
    }
    /* pty -> AVR: read what the host wrote, feed the UART while its fifo has room. Bytes are
     * held while the firmware has not enabled its receiver yet (before Serial.begin). */
    /* -k: host bytes are taken only while simulated time stands still. Taken while it runs, a frame
     * entered the UART at whatever simulated time the harness had reached when the bytes happened to
     * arrive: beside two busy processes the first COMMAND after a CONFIGURE was echoed by SAMPLE 0,
     * on an idle machine by SAMPLE 1 (tests/devices/test_virtual_time.py). */
    if (rx_len < sizeof rx_buf && (!host_paced || gate_closed)) {
        ssize_t r = read(pty_master, rx_buf + rx_len, sizeof rx_buf - rx_len);
        if (r > 0) {
            if (host_paced) on_host_bytes(rx_buf + rx_len, (size_t)r);
            rx_len += (size_t)r;
        }
    }
    if (uart_real) {
        if (rx_len && (avr->data[R_UCSR0B] & (1 << RXEN0_BIT)) && !avr_cycle_timer_status(avr, uart_feed, NULL))
            avr_cycle_timer_register(avr, uart_byte_cycles() + host_delay_cycles(), uart_feed, NULL);
        return;
    }
    size_t fed = 0;
    if (avr->data[R_UCSR0B] & (1 << RXEN0_BIT)) {
        while (fed < rx_len && !xoff) avr_raise_irq(uart_in_irq, rx_buf[fed++]);
    }
    if (fed) { memmove(rx_buf, rx_buf + fed, rx_len - fed); rx_len -= fed; }
}

static void external_reset(void);

/* Commands from the driver, one per line (README.md). Returns 1 when G was read. */
static int handle_line(char *line) {
    long a = 0, b = 0, c = 0, d = 0;
    switch (line[0]) {
        case 'E': if (sscanf(line + 1, "%ld", &a) == 1) { enc_target = (int32_t)a; encoder_kick(); } return 0;
        case 'J': /* jump: set the count without edges (test setup only) */
            if (sscanf(line + 1, "%ld", &a) == 1) { enc_pos = enc_target = (int32_t)a; drive_inputs(); }
            return 0;
        case 'A':
            if (sscanf(line + 1, "%ld %ld", &a, &b) == 2 && a >= 0 && a < 8) {
                adc_mv[a] = (uint32_t)b;
                avr_raise_irq(adc_irq + a, (uint32_t)b);
            }
            return 0;
        case 'P':  /* P ch mV us: hold the ADC input at mV for us of simulated time, then back (a noise burst) */
            if (sscanf(line + 1, "%ld %ld %ld", &a, &b, &c) == 3 && a >= 0 && a < 8 && c > 0) {
                pulse_ch = (int)a;
                avr_raise_irq(adc_irq + a, (uint32_t)b);
                avr_cycle_timer_register(avr, (avr_cycle_count_t)c * CYC_PER_US, pulse_end, NULL);
            }
            return 0;
        case 'D':
            if (sscanf(line + 1, "%ld %ld", &a, &b) == 2 && a == 4) { estop_level = b ? 1 : 0; drive_inputs(); }
            return 0;
        case 'S': report_state(); return 0;
        case 'M':  /* M addr: peek one byte of the data space (registers, I/O, SRAM) */
            if (sscanf(line + 1, "%li", &a) == 1 && a >= 0 && a <= (long)avr->ramend)
                reply("M %ld %u\n", a, avr->data[a]);
            return 0;
        case 'U':  /* UART diagnostics: bytes waiting for the UART, XOFF, UCSR0A, UCSR0B, (-u) bytes fed, overruns,
                    * (-k) COMMANDs and requests not answered yet, whether time stands still */
            reply("U %zu %d 0x%02x 0x%02x %llu %llu %llu %llu %d\n", rx_len, xoff, avr->data[R_UCSR0B - 1],
                  avr->data[R_UCSR0B], (unsigned long long)rx_fed, (unsigned long long)rx_overrun,
                  (unsigned long long)owed[OWE_SAMPLE], (unsigned long long)(owed[OWE_HELLO] + owed[OWE_ACK] + owed[OWE_HEARTBEAT]),
                  gate_closed);
            return 0;
        case 'H':  /* H us: the host's reaction time from now on (as -d) */
            if (sscanf(line + 1, "%ld", &a) == 1 && a >= 0) host_delay_us = (uint32_t)a;
            return 0;
        case 'R':  /* external reset (the RESET pin); never from a cycle timer: it crashed simavr */
            external_reset();
            return 0;
        case 'Q': stop = 1; return 1;
        case 'G': {
            int n = sscanf(line + 1, "%ld %ld %ld %ld", &a, &b, &c, &d);
            if (n >= 1) { enc_target = (int32_t)a; encoder_kick(); }
            if (n >= 2) { adc_mv[0] = (uint32_t)b; avr_raise_irq(adc_irq + 0, (uint32_t)b); }
            if (n >= 3) { adc_mv[1] = (uint32_t)c; avr_raise_irq(adc_irq + 1, (uint32_t)c); }
            if (n >= 4 && (d ? 1 : 0) != estop_level) { estop_level = d ? 1 : 0; drive_inputs(); }
            return 1;
        }
        default: return 0;
    }
}

static char in_buf[8192];

/* The RESET pin pulled low (R, or DTR on port open with -r): MCUSR says EXTRF; a loaded
 * bootloader runs first (BOOTRST). */
static void external_reset(void) {
    avr_reset(avr);
    if (boot_hex) avr->pc = boot_pc;
    avr->data[R_MCUSR] |= 0x02;  /* EXTRF */
    resets++;
    apply_workarounds();
}

/* -r: the pty's hang-up state says whether a host has it open; an open is DTR going up. */
static void watch_port_open(void) {
    struct pollfd p = {.fd = pty_master, .events = POLLIN};
    int open_now = poll(&p, 1, 0) >= 0 && !(p.revents & POLLHUP);
    if (open_now && !host_open) { rx_len = 0; tx_len = 0; external_reset(); }
    host_open = open_now;
}

/* -b: the bootloader image into flash (it must not overlap the sketch); the reset vector moves to it. */
static int load_bootloader(const char *path) {
    ihex_chunk_p chunks = NULL;
    int n = read_ihex_chunks(path, &chunks);
    if (n <= 0) { fprintf(stderr, "avr_harness: cannot read %s\n", path); return -1; }
    uint32_t lowest = UINT32_MAX;
    for (int i = 0; i < n; i++) {
        if (chunks[i].baseaddr + chunks[i].size > avr->flashend + 1) {
            fprintf(stderr, "avr_harness: %s: %u bytes at 0x%04x run past the end of flash (0x%04x)\n", path,
                    chunks[i].size, chunks[i].baseaddr, avr->flashend);
            free_ihex_chunks(chunks);
            return -1;
        }
        memcpy(avr->flash + chunks[i].baseaddr, chunks[i].data, chunks[i].size);
        if (chunks[i].size > 2 && chunks[i].baseaddr < lowest) lowest = chunks[i].baseaddr;  /* not the version word */
    }
    free_ihex_chunks(chunks);
    boot_pc = lowest;
    avr->reset_pc = lowest;
    avr->pc = lowest;
    return 0;
}
static size_t in_len = 0;

/* Reads stdin; blocking until a G line when `wait_go`. EOF (the driver died) stops us. */
static void read_stdin(int wait_go) {
    for (;;) {
        char *nl;
        while ((nl = memchr(in_buf, '\n', in_len)) != NULL) {
            *nl = 0;
            int go = handle_line(in_buf);
            size_t used = (size_t)(nl - in_buf) + 1;
            memmove(in_buf, in_buf + used, in_len - used);
            in_len -= used;
            if (go && wait_go) return;
        }
        if (stop) return;
        if (wait_go) {
            /* keep the serial link alive while the driver thinks */
            struct pollfd p[2] = {{.fd = 0, .events = POLLIN}, {.fd = pty_master, .events = POLLIN}};
            if (poll(p, 2, 5) < 0 && errno != EINTR) { stop = 1; return; }
            pump_pty();
        }
        ssize_t r = read(0, in_buf + in_len, sizeof in_buf - 1 - in_len);
        if (r == 0) { stop = 1; return; }
        if (r < 0) {
            if (errno == EAGAIN || errno == EINTR) { if (!wait_go) return; continue; }
            stop = 1; return;
        }
        in_len += (size_t)r;
        if (in_len >= sizeof in_buf - 1) in_len = 0; /* a line that long is garbage */
    }
}

/* Simulated time may not run ahead of the wall clock; when the simulation falls more than
 * MAX_LAG_US behind (a slow host, a lockstep driver that thinks), the origin moves so that it
 * does not then race to catch up. Waiting happens in ppoll() on the pty and the driver pipe. */
static void throttle(void) {
    int64_t ahead = ((int64_t)sim_us() - sim_origin_us) - (int64_t)wall_us();
    if (ahead < -(int64_t)MAX_LAG_US) sim_origin_us -= -ahead - MAX_LAG_US;
    if (ahead <= 200) return;  /* below ~0.2 ms a sleep costs more than it gains */
    struct timespec ts = {.tv_sec = ahead / 1000000, .tv_nsec = (ahead % 1000000) * 1000};
    struct pollfd p[2] = {{.fd = 0, .events = POLLIN}, {.fd = pty_master, .events = POLLIN}};
    ppoll(p, 2, &ts, NULL);
}

/* -k, while time stands still: sleep until the host or the driver writes (a pty nobody has open
 * reports a hang-up at once, so then sleep a millisecond instead of spinning). */
static void wait_for_io(void) {
    struct pollfd p[2] = {{.fd = 0, .events = POLLIN}, {.fd = pty_master, .events = POLLIN}};
    if (poll(p, 2, 100) > 0 && (p[1].revents & POLLHUP) && !(p[0].revents & POLLIN) && !(p[1].revents & POLLIN)) {
        struct timespec ms = {.tv_sec = 0, .tv_nsec = 1000000};
        nanosleep(&ms, NULL);
    }
}

static void on_signal(int sig) { (void)sig; stop = 1; }

int main(int argc, char **argv) {
    int opt;
    while ((opt = getopt(argc, argv, "fkl:e:b:d:ruv")) != -1) {
        switch (opt) {
            case 'f': free_running = 1; break;
            case 'k': host_paced = 1; free_running = 1; break;
            case 'd': host_delay_us = (uint32_t)strtoul(optarg, NULL, 10); break;
            case 'l': lockstep_us = (uint32_t)strtoul(optarg, NULL, 10); break;
            case 'e': edge_us = (uint32_t)strtoul(optarg, NULL, 10); if (!edge_us) edge_us = 1; break;
            case 'v': verbose = 1; break;
            case 'b': boot_hex = optarg; break;
            case 'r': reset_on_open = 1; break;
            case 'u': uart_real = 1; break;
            default: fprintf(stderr, "usage: %s [-f] [-k] [-d delay_us] [-l lockstep_us] [-e edge_us] [-v] firmware.elf\n", argv[0]); return 2;
        }
    }
    if (optind >= argc) { fprintf(stderr, "avr_harness: no firmware ELF given\n"); return 2; }

    prctl(PR_SET_PDEATHSIG, SIGTERM);  /* never outlive the driver */
    signal(SIGTERM, on_signal);
    signal(SIGINT, on_signal);
    signal(SIGPIPE, SIG_IGN);
    reply_fd = dup(1);
    dup2(2, 1);  /* anything simavr prints goes to stderr, never into the reply stream */
    avr_global_logger_set(logger);

    elf_firmware_t fw;
    memset(&fw, 0, sizeof fw);
    if (elf_read_firmware(argv[optind], &fw) != 0) { fprintf(stderr, "avr_harness: cannot read %s\n", argv[optind]); return 1; }
    avr = avr_make_mcu_by_name("atmega328p");
    if (!avr) { fprintf(stderr, "avr_harness: no atmega328p core\n"); return 1; }
    avr_init(avr);
    fw.frequency = F_CPU;
    avr_load_firmware(avr, &fw);
    avr->frequency = F_CPU;
    avr->vcc = avr->avcc = avr->aref = 5000;  /* else the ADC falls back to 3300 mV */
    if (boot_hex && load_bootloader(boot_hex) != 0) return 1;
    uart0 = (avr_uart_t *)avr->io[AVR_DATA_TO_IO(R_UDR0)].r.param;  /* the UART's own state (its read hook's param) */
    if (uart_real && !uart0) { fprintf(stderr, "avr_harness: no UART0 read hook\n"); return 1; }

    uart_in_irq = avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUTPUT), on_uart_out, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XOFF), on_xoff, NULL);
    avr_irq_register_notify(avr_io_getirq(avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_OUT_XON), on_xon, NULL);
    for (int i = 0; i < 8; i++) pin_irq[i] = avr_io_getirq(avr, AVR_IOCTL_IOPORT_GETIRQ('D'), i);
    adc_irq = avr_io_getirq(avr, AVR_IOCTL_ADC_GETIRQ, ADC_IRQ_ADC0);
    apply_workarounds();

    /* Our own pty: a unique path per run, so parallel harnesses never collide. */
    if (openpty(&pty_master, &pty_slave, NULL, NULL, NULL) != 0) { perror("openpty"); return 1; }
    struct termios tio;
    tcgetattr(pty_slave, &tio);
    cfmakeraw(&tio);
    tcsetattr(pty_slave, TCSANOW, &tio);
    fcntl(pty_master, F_SETFL, fcntl(pty_master, F_GETFL) | O_NONBLOCK);
    fcntl(0, F_SETFL, fcntl(0, F_GETFL) | O_NONBLOCK);
    /* The slave stays open here too, so the master never sees EIO between host connections; with
     * -r it is closed, so the master's hang-up state shows when a host opens the port. */
    reply("%s\n", ttyname(pty_slave));
    if (reset_on_open) { close(pty_slave); pty_slave = -1; }

    clock_gettime(CLOCK_MONOTONIC, &wall0);
    uint64_t next_step = lockstep_us;
    while (!stop) {
        if (gate_closed) {  /* -k: time stands still until a whole host frame has arrived */
            pump_pty();
            if (reset_on_open) watch_port_open();
            if (nothing_owed()) {
                wait_for_io();
                read_stdin(0);
                continue;
            }
            gate_closed = 0;
        }
        avr_cycle_count_t end = avr->cycle + SLICE_US * CYC_PER_US;
        if (lockstep_us && end > next_step * CYC_PER_US) end = next_step * CYC_PER_US;
        while (avr->cycle < end && !gate_closed) {
            int st = avr_run(avr);
            if (st == cpu_Done || st == cpu_Crashed) {
                fprintf(stderr, "avr_harness: AVR %s at pc 0x%04x\n", st == cpu_Done ? "stopped" : "crashed", avr->pc);
                reply("X %d\n", st);
                stop = 1;
                break;
            }
        }
        if (avr_extint_is_strict_lvl_trig(avr, 0) == 1) {  /* the AVR reset (hardware watchdog) */
            resets++;
            apply_workarounds();
        }
        if (reset_on_open) watch_port_open();
        pump_pty();
        if (lockstep_us && sim_us() >= next_step) {
            report_state();
            read_stdin(1);
            next_step += lockstep_us;
        } else {
            read_stdin(0);
        }
        if (!free_running) throttle();
    }
    if (tx_len) pump_pty();
    return 0;
}
