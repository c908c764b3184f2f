/*
 * scale_board.c — a simulated Arduino Uno running the tactile-rig scale sketch, with an HX711.
 *
 * libsimavr runs the sketch's .elf on an ATmega328P at 16 MHz. Around it this program models the
 * rest of the board:
 *
 *   - the USB-serial side: UART0 bridged to a pty whose slave path it prints; bytes reach the AVR
 *     at the host's baud rate (10 bits a byte) and the host at the AVR's; a host at the wrong baud
 *     sees garbage, as on a real line; the USART transmitter is silicon's (see uart_fix_install);
 *   - the DTR auto-reset: the MCU resets when a client opens the pty (seen on the master, which
 *     reads EIO while no client holds the slave); then the Uno's bootloader keeps it silent for
 *     --bootloader-ms (its time-outs, not its code: Debian's optiboot build does not fit the
 *     Uno's boot section), and host bytes sent meanwhile are lost;
 *   - an HX711 on D4 (DOUT) and D5 (PD_SCK): conversions at 10 or 80 per second through a sinc4
 *     filter (a load step settles over 4 conversions; after power-up or a channel/gain change the
 *     first data comes 4 periods later), 24-bit two's complement saturating at 0x7FFFFF/0x800000,
 *     channel and gain picked by 25/26/27 pulses, power-down when PD_SCK stays high 60 us, and a
 *     count of every timing rule the sketch breaks (PD_SCK high > 50 us or < 0.2 us, low < 0.2 us,
 *     clocking while DOUT is high, a wrong pulse count), conversions nobody read counted apart from
 *     those lost between an MCU reset and the sketch powering the chip down (a reset that cuts a
 *     read short leaves the HX711 shifting with PD_SCK floating low); the bridge's offset, counts per gram,
 *     warm-up drift, output noise and rare glitches as the Python mock has them;
 *   - the load, set by the host through a control FIFO (lines "force_n <newtons>", "hx711
 *     connect|disconnect", "reset", "stats <path>", "quit");
 *   - EEPROM kept in a file across resets and runs.
 *
 * Simulated cycles are paced to the wall clock (a sleeping AVR skips to its next event). Two modes:
 *   pty     (default) serve until SIGINT/SIGTERM; first stdout line: {"port": "/dev/pts/N", ...}
 *   script  (--script FILE) run a timed host script as fast as possible, no pty, and print what
 *           the host would have received, one line each: "L <t_first_us> <t_last_us> <hex>"
 *           (times of the first and last byte's stop bit), then "STATS <json>". Script lines:
 *           "<t_ms> open|close|reset|baud <n>|send <hex>|force_n <N>|hx711 connect|disconnect|end".
 *           --trace 1 adds "H <t_us> powerup|data|read|lost <value>" HX711 events, 2 every byte.
 */

#define _GNU_SOURCE
#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <poll.h>
#include <signal.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/prctl.h>
#include <sys/inotify.h>
#include <sys/stat.h>
#include <termios.h>
#include <time.h>
#include <unistd.h>

#include "sim_avr.h"
#include "sim_elf.h"
#include "sim_io.h"
#include "sim_irq.h"
#include "sim_cycle_timers.h"
#include "avr_uart.h"
#include "avr_ioport.h"
#include "avr_eeprom.h"

#define F_CPU 16000000ULL
#define MCUSR_ADDR 0x54           /* data-space address of MCUSR on the ATmega328P */
#define MCUSR_EXTRF (1 << 1)
#define EEPROM_SIZE 1024
#define HX_PIN_DOUT 4             /* PD4 = Arduino D4 */
#define HX_PIN_SCK 5              /* PD5 = Arduino D5 */
#define HX_MIN_COUNTS (-8388608L)
#define HX_MAX_COUNTS 8388607L
#define HX_SETTLE_PERIODS 4       /* sinc4: settled 4 conversion periods after a reset or gain change */
#define STANDARD_GRAVITY 9.80665
/* The Uno's optiboot after an external reset: the 65 ms reset time-out, 3 LED flashes (6 x 62.46 ms),
 * its 1.024 s watchdog time-out waiting for an upload, then 65 ms again after the watchdog reset. */
#define BOOTLOADER_MS 1529.0
#define IN_QUEUE_MAX 256          /* host bytes buffered here: beyond it the host's write blocks */
#define OUT_QUEUE_MAX 8192        /* bytes towards a host that does not read: beyond it they are lost */
#define SLICE_CYCLES 4000         /* 0.25 ms of simulated time between I/O checks */
#define MAX_LAG_NS 250000000LL    /* behind the wall clock by more than this: slip instead of rushing */

/* ---- small helpers -------------------------------------------------------------------------- */

static FILE *proto;               /* the real stdout: our protocol lines only */
static int trace;                 /* script mode: also print HX711 events ("H <t_us> <what> ...") */

static void die(const char *fmt, ...) {
	va_list ap;
	va_start(ap, fmt);
	fprintf(stderr, "scale_board: ");
	vfprintf(stderr, fmt, ap);
	fprintf(stderr, "\n");
	va_end(ap);
	exit(2);
}

static int64_t mono_ns(void) {
	struct timespec ts;
	clock_gettime(CLOCK_MONOTONIC, &ts);
	return (int64_t)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static int64_t floor_div(int64_t n, int64_t d) {  /* d > 0 */
	int64_t q = n / d;
	return (n % d != 0 && n < 0) ? q - 1 : q;
}

static int64_t div_round(int64_t n, int64_t d) {  /* half away from zero, d > 0 */
	return n >= 0 ? (n + d / 2) / d : -((-n + d / 2) / d);
}

static uint64_t rng_state = 0x9E3779B97F4A7C15ULL;

static uint64_t rng_next(void) {  /* xorshift64* */
	rng_state ^= rng_state >> 12;
	rng_state ^= rng_state << 25;
	rng_state ^= rng_state >> 27;
	return rng_state * 2685821657736338717ULL;
}

static double rng_uniform(void) {
	return ((rng_next() >> 11) + 0.5) * (1.0 / 9007199254740992.0);
}

static double rng_gauss(void) {  /* Box-Muller */
	double u = rng_uniform(), v = rng_uniform();
	return sqrt(-2.0 * log(u)) * cos(2.0 * M_PI * v);
}

/* ---- options ------------------------------------------------------------------------------- */

typedef struct {
	const char *elf, *eeprom_path, *control_path, *script_path, *pty_link;
	int rate_sps, boot_junk;
	double bootloader_ms, counts_per_g, offset_counts, noise_counts, channel_b_counts, force_n;
	double drift_counts, drift_tau_s, spike_prob;
	uint64_t seed;
} options_t;

/* ---- the board ------------------------------------------------------------------------------ */

typedef struct {
	/* HX711 */
	int connected, powered, sck, reading, pulses, gain, settle_left, ready, dout, busy_rise;
	int orphaned;                 /* the MCU reset since it last powered the chip down: nobody reads it */
	avr_cycle_count_t period, next_conv, pd_at, sck_rise, sck_fall;
	int64_t hist[HX_SETTLE_PERIODS];
	int nhist;
	int32_t data;
	uint64_t conversions, reads, missed, powerdowns;
	uint64_t missed_after_reset, reads_cut_by_reset; /* the reset's doing, not the sketch's */
	uint64_t v_high_long, v_high_short, v_low_short, v_busy, v_pulses;
} hx711_t;

typedef struct {
	avr_t *avr;
	options_t opt;
	hx711_t hx;
	avr_irq_t *dout_irq, *uart_in_irq;
	/* host link */
	int host_open, host_baud, script;
	int master;                   /* pty master, -1 in script mode */
	uint8_t inq[IN_QUEUE_MAX];
	int inq_len;
	avr_cycle_count_t feed_at;    /* next host byte's start bit reaches the AVR; 0 = idle */
	avr_cycle_count_t in_free;    /* when the host-to-AVR line is free again */
	struct { uint8_t b; avr_cycle_count_t ready; } outq[OUT_QUEUE_MAX];
	int outq_head, outq_len;
	avr_cycle_count_t out_free;   /* when the line towards the host is free again */
	avr_cycle_count_t stop_at;    /* bounds a sleeping AVR's jump (slice end, next script event) */
	avr_cycle_count_t boot_until; /* the AVR sits in the bootloader until then; 0 = running the sketch */
	/* EEPROM */
	uint8_t ee_saved[EEPROM_SIZE];
	/* script-mode line assembly */
	uint8_t line[4096];
	int line_len;
	avr_cycle_count_t line_t0;
	/* stats */
	uint64_t resets, to_avr, from_avr, out_dropped, garbled, slips;
	int64_t lag_max_ns;
} board_t;

static board_t B;
static avr_uart_t *uart0;
static struct {                   /* the USART transmitter (see uart_fix_install) */
	int shifting, udr_full;
	uint8_t udr;
	avr_cycle_count_t shift_end;
	uint64_t overruns;
} tx;
static volatile sig_atomic_t stop_requested = 0;

static avr_cycle_count_t now_cycle(void) { return B.avr->cycle; }

static double cycles_to_s(avr_cycle_count_t c) { return (double)c / (double)F_CPU; }

/* The AVR's UART0 baud from UBRR0 and U2X0, or 0 while it is off. */
static uint32_t avr_baud(void) {
	uint8_t *d = B.avr->data;
	uint16_t ubrr = (uint16_t)(d[0xC4] | ((d[0xC5] & 0x0F) << 8));
	int u2x = (d[0xC0] >> 1) & 1;
	if (!(d[0xC1] & ((1 << 3) | (1 << 4))))  /* neither TXEN0 nor RXEN0 */
		return 0;
	return (uint32_t)(F_CPU / ((u2x ? 8ULL : 16ULL) * (ubrr + 1ULL)));
}

/* A receiver more than 4 % off the sender's baud reads framing garbage. */
static int baud_mismatch(uint32_t a, uint32_t b) {
	if (!a || !b) return 0;
	double r = (double)a / (double)b;
	return r < 0.96 || r > 1.04;
}

/* ---- the scheduler: one simavr cycle timer for everything this board does ---------------------- */

static avr_cycle_count_t board_tick(avr_t *avr, avr_cycle_count_t when, void *param);

static avr_cycle_count_t next_event(void) {
	avr_cycle_count_t n = B.stop_at;
	if (B.hx.powered && B.hx.next_conv && (!n || B.hx.next_conv < n)) n = B.hx.next_conv;
	if (B.hx.pd_at && (!n || B.hx.pd_at < n)) n = B.hx.pd_at;
	if (B.feed_at && (!n || B.feed_at < n)) n = B.feed_at;
	if (tx.shifting && (!n || tx.shift_end < n)) n = tx.shift_end;
	return n;
}

static void reschedule(void) {
	avr_cycle_timer_cancel(B.avr, board_tick, NULL);
	avr_cycle_count_t n = next_event();
	if (n) {
		avr_cycle_count_t now = now_cycle();
		avr_cycle_timer_register(B.avr, n > now ? n - now : 1, board_tick, NULL);
	}
}

/* ---- HX711 ---------------------------------------------------------------------------------- */

static void hx_drive_dout(int level) {
	B.hx.dout = level;
	avr_raise_irq(B.dout_irq, level ? 1 : 0);
}

static int64_t hx_input_counts(avr_cycle_count_t t) {
	/* The bridge's output as counts at gain 128: zero offset plus the load. */
	double grams = B.opt.force_n / STANDARD_GRAVITY * 1000.0;
	if (B.hx.gain == 32)
		return (int64_t)floor(B.opt.channel_b_counts + 0.5);
	double counts = B.opt.offset_counts + B.opt.counts_per_g * grams;
	if (B.opt.drift_counts != 0.0)         /* the bridge and the HX711 warming up since power-on */
		counts += B.opt.drift_counts * (1.0 - exp(-cycles_to_s(t) / B.opt.drift_tau_s));
	return (int64_t)floor(counts + 0.5);
}

static void hx_trace(const char *what, avr_cycle_count_t t, long long v) {
	if (trace) fprintf(proto, "H %.3f %s %lld\n", cycles_to_s(t) * 1e6, what, v);
}

static void hx_power_up(avr_cycle_count_t t) {
	hx711_t *h = &B.hx;
	hx_trace("powerup", t, 0);
	h->powered = 1;
	h->gain = 128;                          /* after a reset: channel A, gain 128 */
	h->nhist = 0;
	h->settle_left = HX_SETTLE_PERIODS;
	h->ready = h->reading = h->pulses = 0;
	h->next_conv = t + h->period;
	hx_drive_dout(1);
}

static void hx_power_down(void) {
	hx711_t *h = &B.hx;
	if (h->powered) h->powerdowns++;
	h->powered = 0;
	h->orphaned = 0;                        /* a sketch that powers it down is the one reading it next */
	h->ready = h->reading = h->pulses = 0;
	h->next_conv = 0;
	hx_drive_dout(1);                       /* DOUT high; an unplugged one reads high through the pull-up */
}

static void hx_present(int32_t value) {
	hx711_t *h = &B.hx;
	if (h->ready) {                         /* the one before was never read */
		if (B.boot_until || h->orphaned) h->missed_after_reset++;
		else h->missed++;
	}
	hx_trace("data", now_cycle(), value);
	h->data = value;
	h->ready = 1;
	h->pulses = 0;
	hx_drive_dout(0);
}

static void hx_convert(avr_cycle_count_t t) {
	hx711_t *h = &B.hx;
	h->next_conv = t + h->period;
	/* The pulses after the last read chose this conversion's channel and gain. */
	if (h->pulses) {
		int g = h->pulses == 25 ? 128 : h->pulses == 26 ? 32 : h->pulses == 27 ? 64 : 0;
		if (!g) {
			if (!h->orphaned) h->v_pulses++;        /* a read cut by a reset is not the sketch's count */
		} else if (g != h->gain) {
			h->gain = g;
			h->nhist = 0;
			h->settle_left = HX_SETTLE_PERIODS;
		}
		h->pulses = 0;
	}
	int64_t x = hx_input_counts(t);
	if (h->gain != 128) x = div_round(x * h->gain, 128);
	for (int i = HX_SETTLE_PERIODS - 1; i > 0; i--) h->hist[i] = h->hist[i - 1];
	h->hist[0] = x;
	if (h->nhist < HX_SETTLE_PERIODS) h->nhist++;
	if (h->settle_left && --h->settle_left) return;
	h->conversions++;
	/* sinc4: each period's input weighted by the filter's response over it (1, 11, 11, 1) / 24. */
	int64_t out = floor_div(h->hist[0] + 11 * h->hist[1] + 11 * h->hist[2] + h->hist[3] + 12, 24);
	if (B.opt.noise_counts > 0) out += (int64_t)floor(B.opt.noise_counts * rng_gauss() + 0.5);
	if (B.opt.spike_prob > 0 && rng_uniform() < B.opt.spike_prob)
		out ^= (int64_t)1 << (17 + (int)(rng_next() % 6));  /* a glitched conversion: one high bit flipped */
	if (out < HX_MIN_COUNTS) out = HX_MIN_COUNTS;
	if (out > HX_MAX_COUNTS) out = HX_MAX_COUNTS;
	if (h->reading) {
		/* The output register is being shifted out: lost. A read a reset cut short stays "being
		 * shifted out" with PD_SCK floating low until the sketch powers the chip down. */
		if (B.boot_until || h->orphaned) h->missed_after_reset++;
		else h->missed++;
		hx_trace("lost", t, out);
	} else {
		hx_present((int32_t)out);
	}
}

static void hx_sck_changed(struct avr_irq_t *irq, uint32_t value, void *param) {
	(void)irq; (void)param;
	hx711_t *h = &B.hx;
	avr_cycle_count_t t = now_cycle();
	int level = value ? 1 : 0;
	if (level == h->sck) return;
	h->sck = level;
	if (level) {
		if (h->reading && t - h->sck_fall < 4) h->v_low_short++;     /* < 0.25 us */
		h->sck_rise = t;
		h->pd_at = t + 960;                                          /* 60 us */
		h->busy_rise = 0;
		if (h->powered) {
			if (h->ready || h->reading) {
				if (!h->reading) {
					h->reads++;
					hx_trace("read", t, 0);
				}
				h->reading = 1;
				h->pulses++;
				if (h->pulses <= 24) {
					hx_drive_dout((int)(((uint32_t)h->data >> (24 - h->pulses)) & 1));
				} else if (h->pulses == 25) {
					h->ready = 0;
					h->reading = 0;
					hx_drive_dout(1);                                /* the 25th pulse pulls DOUT high */
				}
			} else if (h->pulses >= 25) {
				h->pulses++;                                         /* 26th, 27th: channel and gain */
			} else {
				h->busy_rise = 1;                                    /* a clock, or a power-down pulse? */
			}
		}
	} else {
		avr_cycle_count_t high = t - h->sck_rise;
		h->pd_at = 0;
		h->sck_fall = t;
		if (h->powered) {
			if (h->busy_rise) h->v_busy++;                           /* clocked while DOUT was high */
			if (high > 800) h->v_high_long++;                        /* > 50 us */
			else if (high < 4 && h->pulses) h->v_high_short++;       /* < 0.25 us */
		} else if (B.hx.connected) {
			hx_power_up(t);                                          /* PD_SCK low again: reset */
		}
	}
	reschedule();
}

/* ---- UART bridge ----------------------------------------------------------------------------- */

static void out_push_at(uint8_t b, avr_cycle_count_t sent, uint32_t baud, int junk) {
	avr_cycle_count_t per_byte = baud ? (avr_cycle_count_t)(10ULL * F_CPU / baud) : 2800;
	avr_cycle_count_t start = sent > B.out_free ? sent : B.out_free;
	B.out_free = start + per_byte;
	if (!B.host_open) return;               /* nobody listening: the USB chip drops it */
	if (!junk && B.host_baud && baud_mismatch(B.host_baud, baud)) {
		b = (uint8_t)rng_next();
		B.garbled++;
	}
	if (B.outq_len >= OUT_QUEUE_MAX) {
		B.out_dropped++;
		return;
	}
	int i = (B.outq_head + B.outq_len) % OUT_QUEUE_MAX;
	B.outq[i].b = b;
	B.outq[i].ready = B.out_free;
	if (trace > 1) fprintf(proto, "T %.3f %.3f %02x\n", cycles_to_s(sent) * 1e6, cycles_to_s(B.out_free) * 1e6, b);
	B.outq_len++;
}

/* A byte the AVR sends: on the wire after the byte before it, one frame at the AVR's baud. */
static void out_push(uint8_t b, avr_cycle_count_t sent) {
	out_push_at(b, sent, avr_baud(), 0);
}

/* Two fixes to libsimavr 1.6's USART, so the sketch sees the timing of silicon:
 *   - it counts a parity bit in every frame (11 bit times for 8N1): after each write to the baud
 *     or frame registers, the 10 bit times of 8N1 are set back;
 *   - its transmitter holds one byte: UDRE comes back only when that byte is fully sent. Silicon
 *     has the UDR buffer in front of the shift register, so UDRE is set again as soon as a byte
 *     moves into the shift register, and Serial.write() gets one byte further before it blocks.
 *     The board takes over UDR0 writes and runs that two-stage transmitter itself. */

static avr_cycle_count_t uart_cycles_per_byte(void) {
	uint32_t baud = avr_baud();
	return baud ? (avr_cycle_count_t)(10ULL * F_CPU / baud) : 2720;
}

static void uart_frame_fix(struct avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param) {
	(void)avr; (void)addr; (void)v; (void)param;
	if (uart0 && avr_baud()) uart0->cycles_per_byte = uart_cycles_per_byte();
	if (uart0 && tx.udr_full) {
		/* simavr raises UDRE when UDRIE is enabled and its own transmitter is idle: ours is not. */
		avr_clear_interrupt(B.avr, &uart0->udrc);
		avr_regbit_clear(B.avr, uart0->udrc.raised);
	}
}

static void uart_udr_write(struct avr_t *avr, avr_io_addr_t addr, uint8_t v, void *param) {
	(void)addr; (void)param;
	if (!(avr->data[0xC1] & (1 << 3)))     /* TXEN0 off: nothing is sent */
		return;
	B.from_avr++;
	if (!tx.shifting) {
		tx.shifting = 1;
		tx.shift_end = now_cycle() + uart_cycles_per_byte();
		out_push(v, now_cycle());
		avr_clear_interrupt(avr, &uart0->txc);
		avr_regbit_clear(avr, uart0->txc.raised);
		avr_raise_interrupt(avr, &uart0->udrc);  /* UDR is free again at once */
	} else if (!tx.udr_full) {
		tx.udr_full = 1;
		tx.udr = v;
		avr_clear_interrupt(avr, &uart0->udrc);
		avr_regbit_clear(avr, uart0->udrc.raised);
	} else {
		tx.overruns++;                      /* written over a full UDR: silicon loses it too */
	}
	reschedule();
}

/* The shift register has sent its byte: the next one moves in from UDR, or the line goes idle. */
static void uart_tx_shift_done(avr_cycle_count_t t) {
	if (tx.udr_full) {
		tx.udr_full = 0;
		out_push(tx.udr, t);
		tx.shift_end = t + uart_cycles_per_byte();
		avr_raise_interrupt(B.avr, &uart0->udrc);
	} else {
		tx.shifting = 0;
		avr_raise_interrupt(B.avr, &uart0->txc);
	}
}

static void uart_tx_reset(void) {
	tx.shifting = tx.udr_full = 0;
}

static void uart_fix_install(void) {
	for (avr_io_t *io = B.avr->io_port; io; io = io->next) {
		if (io->kind && !strcmp(io->kind, "uart") && ((avr_uart_t *)io)->name == '0') uart0 = (avr_uart_t *)io;
	}
	if (!uart0) die("libsimavr: no UART0 on this ATmega328P");
	/* Registered after simavr's own handlers on the same registers, so they run after them. */
	avr_register_io_write(B.avr, 0xC4, uart_frame_fix, NULL);  /* UBRR0L */
	avr_register_io_write(B.avr, 0xC5, uart_frame_fix, NULL);  /* UBRR0H */
	avr_register_io_write(B.avr, 0xC0, uart_frame_fix, NULL);  /* UCSR0A (U2X0) */
	avr_register_io_write(B.avr, 0xC1, uart_frame_fix, NULL);  /* UCSR0B (UDRIE0) */
	avr_register_io_write(B.avr, 0xC2, uart_frame_fix, NULL);  /* UCSR0C (frame format) */
	/* UDR0 has simavr's handler only: replace it with the two-stage transmitter. */
	B.avr->io[AVR_DATA_TO_IO(0xC6)].w.c = uart_udr_write;
	B.avr->io[AVR_DATA_TO_IO(0xC6)].w.param = NULL;
}

static avr_cycle_count_t host_byte_cycles(void) {
	return (avr_cycle_count_t)(10ULL * F_CPU / (B.host_baud ? (uint64_t)B.host_baud : 57600ULL));
}

static void feed_start(void) {
	if (!B.feed_at && B.inq_len) {
		/* The start bit goes out now; simavr flags the byte received one byte time later. */
		B.feed_at = now_cycle() + 1 > B.in_free ? now_cycle() + 1 : B.in_free;
		reschedule();
	}
}

static void feed_one(void) {
	uint8_t b = B.inq[0];
	memmove(B.inq, B.inq + 1, (size_t)--B.inq_len);
	uint32_t baud = avr_baud();
	if (B.host_baud && baud_mismatch(B.host_baud, baud)) {
		b = (uint8_t)rng_next();
		B.garbled++;
	}
	B.to_avr++;
	avr_raise_irq(B.uart_in_irq, b);
	B.in_free = B.feed_at + host_byte_cycles();
	B.feed_at = B.inq_len ? B.in_free : 0;
}

static avr_cycle_count_t board_tick(avr_t *avr, avr_cycle_count_t when, void *param) {
	(void)avr; (void)param;
	hx711_t *h = &B.hx;
	if (h->pd_at && when >= h->pd_at) {
		h->pd_at = 0;
		if (h->sck) {                       /* PD_SCK high for 60 us */
			if (h->reading && h->pulses == 1) h->reads--;  /* that rising edge began no read */
			hx_power_down();
		}
	}
	while (h->powered && h->next_conv && when >= h->next_conv) hx_convert(h->next_conv);
	while (B.feed_at && when >= B.feed_at) feed_one();
	while (tx.shifting && when >= tx.shift_end) uart_tx_shift_done(tx.shift_end);
	if (B.stop_at && when >= B.stop_at) B.stop_at = 0;
	avr_cycle_count_t n = next_event();
	return n ? (n > when ? n : when + 1) : 0;
}

/* ---- reset, EEPROM --------------------------------------------------------------------------- */

static void eeprom_get(uint8_t *buf) {
	avr_eeprom_desc_t d = {.ee = buf, .offset = 0, .size = EEPROM_SIZE};
	avr_ioctl(B.avr, AVR_IOCTL_EEPROM_GET, &d);
	memcpy(buf, d.ee, EEPROM_SIZE);
}

static void eeprom_set(const uint8_t *buf) {
	avr_eeprom_desc_t d = {.ee = (uint8_t *)buf, .offset = 0, .size = EEPROM_SIZE};
	avr_ioctl(B.avr, AVR_IOCTL_EEPROM_SET, &d);
}

static void eeprom_save_if_changed(void) {
	uint8_t now[EEPROM_SIZE];
	eeprom_get(now);
	if (!B.opt.eeprom_path || !memcmp(now, B.ee_saved, EEPROM_SIZE)) return;
	char tmp[4096];
	snprintf(tmp, sizeof tmp, "%s.tmp%d", B.opt.eeprom_path, (int)getpid());
	FILE *f = fopen(tmp, "wb");
	if (!f || fwrite(now, 1, EEPROM_SIZE, f) != EEPROM_SIZE || fclose(f) != 0) {
		fprintf(stderr, "scale_board: cannot write %s: %s\n", tmp, strerror(errno));
		return;
	}
	if (rename(tmp, B.opt.eeprom_path) != 0) {
		fprintf(stderr, "scale_board: cannot rename %s: %s\n", tmp, strerror(errno));
		return;
	}
	memcpy(B.ee_saved, now, EEPROM_SIZE);
}

/* The reset pin pulled low and released: the AVR starts over, the HX711 (its own chip) does not. */
static void board_reset(void) {
	uint8_t ee[EEPROM_SIZE];
	eeprom_get(ee);
	avr_reset(B.avr);                       /* also empties simavr's cycle timers */
	eeprom_set(ee);
	uart_tx_reset();
	B.avr->data[MCUSR_ADDR] = MCUSR_EXTRF;   /* an external reset: optiboot waits for an upload */
	B.boot_until = now_cycle() + (avr_cycle_count_t)llround(B.opt.bootloader_ms * 1e-3 * (double)F_CPU);
	if (B.boot_until == now_cycle()) B.boot_until = 0;
	B.resets++;
	B.inq_len = 0;                          /* bytes on the wire at the reset are lost */
	B.feed_at = 0;
	if (B.hx.reading) B.hx.reads_cut_by_reset++;
	B.hx.orphaned = 1;
	B.hx.sck = 0;                           /* PD_SCK floats low while the pin is an input */
	B.hx.pd_at = 0;
	avr_raise_irq(B.dout_irq, B.hx.dout ? 0 : 1);
	hx_drive_dout(B.hx.dout);
	for (int i = 0; i < B.opt.boot_junk; i++) {
		/* The USB-serial chip often reads a glitch while the AVR's TX pin floats in reset. */
		out_push_at((uint8_t)(0x80 | (rng_next() & 0x7F)), now_cycle(), B.host_baud ? (uint32_t)B.host_baud : 57600, 1);
	}
	reschedule();
}

/* Run the board up to `t` at most: the sketch, or, while the bootloader holds the AVR, only time. */
static void step_to(avr_cycle_count_t t) {
	if (B.boot_until) {
		/* The bootloader's own code is not simulated (Debian's optiboot build does not fit the
		 * Uno's 512-byte boot section); it sends nothing and its UART ignores the host's baud. */
		avr_cycle_count_t to = t < B.boot_until ? t : B.boot_until;
		B.avr->cycle = to;
		avr_cycle_timer_process(B.avr);
		if (to == B.boot_until) {
			/* The watchdog reset that ends it: the sketch starts with MCUSR cleared by optiboot. */
			uint8_t ee[EEPROM_SIZE];
			eeprom_get(ee);
			avr_reset(B.avr);
			eeprom_set(ee);
			uart_tx_reset();
			B.avr->data[MCUSR_ADDR] = 0;
			B.boot_until = 0;
			B.hx.sck = 0;
			B.hx.pd_at = 0;
			avr_raise_irq(B.dout_irq, B.hx.dout ? 0 : 1);
			hx_drive_dout(B.hx.dout);
			reschedule();
		}
		return;
	}
	B.stop_at = t;
	reschedule();
	while (B.stop_at && now_cycle() < t && B.avr->state != cpu_Done && B.avr->state != cpu_Crashed)
		avr_run(B.avr);
	B.stop_at = 0;
}

/* ---- control FIFO ---------------------------------------------------------------------------- */

static void write_stats(FILE *f) {
	hx711_t *h = &B.hx;
	fprintf(f,
		"{\"sim_s\": %.6f, \"resets\": %llu, \"rate_sps\": %d, \"force_n\": %.9g, "
		"\"hx711\": {\"connected\": %d, \"powered\": %d, \"gain\": %d, \"conversions\": %llu, \"reads\": %llu, "
		"\"missed\": %llu, \"missed_after_reset\": %llu, \"reads_cut_by_reset\": %llu, "
		"\"powerdowns\": %llu, \"violations\": {\"sck_high_over_50us\": %llu, "
		"\"sck_high_under_0_2us\": %llu, \"sck_low_under_0_2us\": %llu, \"clocked_while_busy\": %llu, "
		"\"wrong_pulse_count\": %llu}}, "
		"\"uart\": {\"to_avr\": %llu, \"from_avr\": %llu, \"dropped_towards_host\": %llu, \"garbled\": %llu, \"tx_overruns\": %llu}, "
		"\"pacing\": {\"lag_max_ms\": %.3f, \"slips\": %llu}}",
		cycles_to_s(now_cycle()), (unsigned long long)B.resets, B.opt.rate_sps, B.opt.force_n,
		h->connected, h->powered, h->gain, (unsigned long long)h->conversions,
		(unsigned long long)h->reads, (unsigned long long)h->missed,
		(unsigned long long)h->missed_after_reset, (unsigned long long)h->reads_cut_by_reset,
		(unsigned long long)h->powerdowns, (unsigned long long)h->v_high_long,
		(unsigned long long)h->v_high_short, (unsigned long long)h->v_low_short,
		(unsigned long long)h->v_busy, (unsigned long long)h->v_pulses,
		(unsigned long long)B.to_avr, (unsigned long long)B.from_avr,
		(unsigned long long)B.out_dropped, (unsigned long long)B.garbled, (unsigned long long)tx.overruns,
		B.lag_max_ns / 1e6, (unsigned long long)B.slips);
}

static void set_connected(int on) {
	if (on && !B.hx.connected) {
		B.hx.connected = 1;
		if (!B.hx.sck) hx_power_up(now_cycle());
	} else if (!on && B.hx.connected) {
		B.hx.connected = 0;
		hx_power_down();
		B.hx.powerdowns--;                  /* unplugged, not a power-down the sketch asked for */
	}
	reschedule();
}

/* One command from the control FIFO or a script; returns 0 if unknown. */
static int command(const char *cmd) {
	char arg[4096];
	double v;
	if (sscanf(cmd, "force_n %lf", &v) == 1 && isfinite(v)) {
		B.opt.force_n = v;
	} else if (!strcmp(cmd, "hx711 connect")) {
		set_connected(1);
	} else if (!strcmp(cmd, "hx711 disconnect")) {
		set_connected(0);
	} else if (!strcmp(cmd, "reset")) {
		board_reset();
	} else if (sscanf(cmd, "stats %4095s", arg) == 1) {
		char tmp[4200];
		snprintf(tmp, sizeof tmp, "%s.tmp", arg);
		FILE *f = fopen(tmp, "w");
		if (f) {
			write_stats(f);
			fputc('\n', f);
			fclose(f);
			rename(tmp, arg);
		}
	} else if (!strcmp(cmd, "quit")) {
		stop_requested = 1;
	} else {
		return 0;
	}
	return 1;
}

static int control_fd = -1;
static char control_buf[8192];
static size_t control_len = 0;

static void poll_control(void) {
	if (control_fd < 0) return;
	for (;;) {
		ssize_t n = read(control_fd, control_buf + control_len, sizeof control_buf - 1 - control_len);
		if (n <= 0) break;
		control_len += (size_t)n;
		char *nl;
		while ((nl = memchr(control_buf, '\n', control_len)) != NULL) {
			*nl = 0;
			if (nl > control_buf && !command(control_buf))
				fprintf(stderr, "scale_board: unknown control command '%s'\n", control_buf);
			size_t used = (size_t)(nl - control_buf) + 1;
			memmove(control_buf, nl + 1, control_len - used);
			control_len -= used;
		}
		if (control_len == sizeof control_buf - 1) control_len = 0;  /* a line that long is noise */
	}
}

/* ---- pty host --------------------------------------------------------------------------------- */

static int baud_of_speed(speed_t s) {
	static const struct { speed_t s; int b; } t[] = {
		{B1200, 1200}, {B2400, 2400}, {B4800, 4800}, {B9600, 9600}, {B19200, 19200},
		{B38400, 38400}, {B57600, 57600}, {B115200, 115200}, {B230400, 230400},
		{B460800, 460800}, {B500000, 500000}, {B921600, 921600}, {B1000000, 1000000},
		{B2000000, 2000000},
	};
	for (size_t i = 0; i < sizeof t / sizeof t[0]; i++)
		if (t[i].s == s) return t[i].b;
	return 0;
}

static int inotify_fd = -1;
static int slave_opens = 0;       /* clients holding the slave open (inotify) */

static void pty_open_master(void) {
	int m = posix_openpt(O_RDWR | O_NOCTTY);
	if (m < 0 || grantpt(m) || unlockpt(m)) die("cannot allocate a pty: %s", strerror(errno));
	const char *slave = ptsname(m);
	if (!slave) die("ptsname: %s", strerror(errno));
	struct termios tio;
	int s = open(slave, O_RDWR | O_NOCTTY);
	if (s < 0) die("cannot open %s: %s", slave, strerror(errno));
	tcgetattr(s, &tio);
	cfmakeraw(&tio);
	cfsetispeed(&tio, B57600);
	cfsetospeed(&tio, B57600);
	tcsetattr(s, TCSANOW, &tio);
	/* Close our handle: the master now reads EIO until a client opens the slave. */
	close(s);
	fcntl(m, F_SETFL, fcntl(m, F_GETFL) | O_NONBLOCK);
	B.master = m;
	/* inotify sees every open and close of the slave, even a close and reopen within microseconds
	 * (which EIO on the master can miss); EIO stays the fallback where inotify is unavailable. */
	inotify_fd = inotify_init1(IN_NONBLOCK | IN_CLOEXEC);
	if (inotify_fd >= 0 && inotify_add_watch(inotify_fd, slave, IN_OPEN | IN_CLOSE) < 0) {
		close(inotify_fd);
		inotify_fd = -1;
	}
	if (B.opt.pty_link) {
		unlink(B.opt.pty_link);
		if (symlink(slave, B.opt.pty_link) != 0)
			die("cannot link %s -> %s: %s", B.opt.pty_link, slave, strerror(errno));
	}
	fprintf(proto, "{\"port\": \"%s\", \"cpu_hz\": %llu, \"rate_sps\": %d, \"pid\": %d}\n", slave,
		(unsigned long long)F_CPU, B.opt.rate_sps, (int)getpid());
	fflush(proto);
}

static void host_read_baud(void) {
	struct termios tio;
	if (tcgetattr(B.master, &tio) == 0) B.host_baud = baud_of_speed(cfgetospeed(&tio));
}

static void host_opened(void) {
	B.host_open = 1;
	B.outq_len = 0;
	host_read_baud();
	board_reset();                          /* DTR auto-reset */
}

static void host_closed(void) {
	B.host_open = 0;
	B.outq_len = 0;                         /* bytes in flight to a closed port are lost */
	B.inq_len = 0;
	B.feed_at = 0;
}

/* Opens and closes of the slave since the last call, in order: the first open resets the board. */
static void pty_watch_opens(void) {
	char buf[4096] __attribute__((aligned(__alignof__(struct inotify_event))));
	ssize_t n;
	while ((n = read(inotify_fd, buf, sizeof buf)) > 0) {
		for (char *p = buf; p < buf + n;) {
			const struct inotify_event *e = (const struct inotify_event *)p;
			if (e->mask & IN_OPEN) {
				if (slave_opens++ == 0) host_opened();
			} else if (e->mask & (IN_CLOSE_WRITE | IN_CLOSE_NOWRITE)) {
				if (slave_opens > 0 && --slave_opens == 0) host_closed();
			}
			p += sizeof(struct inotify_event) + e->len;
		}
	}
}

/* Exchange bytes with the pty; notice opens and closes. */
static void pty_service(void) {
	if (inotify_fd >= 0) {
		pty_watch_opens();
		if (!B.host_open) return;
	} else if (!B.host_open) {
		uint8_t buf[IN_QUEUE_MAX];
		ssize_t n = read(B.master, buf, sizeof buf);
		if (n < 0 && errno == EIO) return;  /* still nobody on the slave */
		host_opened();
		if (n > 0) {
			memcpy(B.inq, buf, (size_t)n);
			B.inq_len = (int)n;
			feed_start();
		}
		return;
	}
	if (B.inq_len < IN_QUEUE_MAX) {
		ssize_t n = read(B.master, B.inq + B.inq_len, (size_t)(IN_QUEUE_MAX - B.inq_len));
		if (n < 0 && errno == EIO) {
			if (inotify_fd < 0) host_closed();  /* with inotify, its close event says so */
			return;
		}
		if (n > 0) {
			host_read_baud();               /* clients may change the baud rate at any time */
			B.inq_len += (int)n;
			feed_start();
		}
	}
	avr_cycle_count_t now = now_cycle();
	uint8_t buf[OUT_QUEUE_MAX];
	int n = 0;
	while (B.outq_len && B.outq[B.outq_head].ready <= now) {
		buf[n++] = B.outq[B.outq_head].b;
		B.outq_head = (B.outq_head + 1) % OUT_QUEUE_MAX;
		B.outq_len--;
	}
	for (int off = 0; off < n;) {
		ssize_t w = write(B.master, buf + off, (size_t)(n - off));
		if (w > 0) {
			off += (int)w;
		} else if (w < 0 && errno == EAGAIN) {
			B.out_dropped += (uint64_t)(n - off);  /* the host does not read: its buffer is full */
			break;
		} else {
			if (w < 0 && errno == EIO && inotify_fd < 0) host_closed();
			break;
		}
	}
}

static void run_pty(void) {
	pty_open_master();
	int64_t wall0 = mono_ns();
	avr_cycle_count_t cyc0 = now_cycle();
	while (!stop_requested && B.avr->state != cpu_Done && B.avr->state != cpu_Crashed) {
		/* Host input first (it may have woken us), then a slice, then what the slice sent. */
		pty_service();
		poll_control();
		step_to(now_cycle() + SLICE_CYCLES);
		pty_service();
		static avr_cycle_count_t last_ee = 0;
		if (now_cycle() - last_ee > F_CPU / 10) {
			eeprom_save_if_changed();
			last_ee = now_cycle();
		}
		/* Pace: simulated time may not run ahead of the wall clock. */
		int64_t sim_ns = (int64_t)((now_cycle() - cyc0) * 1000000000ULL / F_CPU);
		int64_t wall_ns = mono_ns() - wall0;
		if (sim_ns > wall_ns) {
			int64_t wait_ns = sim_ns - wall_ns;
			struct pollfd p[2] = {{.fd = control_fd, .events = POLLIN}, {.fd = B.host_open ? B.master : -1, .events = POLLIN}};
			struct timespec ts = {.tv_sec = wait_ns / 1000000000LL, .tv_nsec = wait_ns % 1000000000LL};
			ppoll(p, 2, &ts, NULL);
		} else {
			int64_t lag = wall_ns - sim_ns;
			if (lag > B.lag_max_ns) B.lag_max_ns = lag;
			if (lag > MAX_LAG_NS) {         /* stopped or starved: carry on from here, do not rush */
				wall0 += lag;
				B.slips++;
			}
		}
	}
	eeprom_save_if_changed();
}

/* ---- script host ------------------------------------------------------------------------------ */

static void script_emit_line(avr_cycle_count_t t_last) {
	fprintf(proto, "L %.1f %.1f ", cycles_to_s(B.line_t0) * 1e6, cycles_to_s(t_last) * 1e6);
	for (int i = 0; i < B.line_len; i++) fprintf(proto, "%02x", B.line[i]);
	fputc('\n', proto);
	B.line_len = 0;
}

/* Bytes that have reached the host by now become output lines. */
static void script_collect(void) {
	avr_cycle_count_t now = now_cycle();
	while (B.outq_len && B.outq[B.outq_head].ready <= now) {
		uint8_t b = B.outq[B.outq_head].b;
		avr_cycle_count_t t = B.outq[B.outq_head].ready;
		B.outq_head = (B.outq_head + 1) % OUT_QUEUE_MAX;
		B.outq_len--;
		if (!B.line_len) B.line_t0 = t;
		if (B.line_len < (int)sizeof B.line) B.line[B.line_len++] = b;
		if (b == '\n') script_emit_line(t);
	}
}

static int hexval(int c) {
	return c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10 : c >= 'A' && c <= 'F' ? c - 'A' + 10 : -1;
}

static void run_until(avr_cycle_count_t t) {
	while (now_cycle() < t && B.avr->state != cpu_Done && B.avr->state != cpu_Crashed) {
		avr_cycle_count_t slice = now_cycle() + SLICE_CYCLES;
		step_to(slice < t ? slice : t);
		script_collect();
	}
}

static void run_script(void) {
	FILE *f = fopen(B.opt.script_path, "r");
	if (!f) die("cannot read the script %s: %s", B.opt.script_path, strerror(errno));
	char ln[65536];
	int lineno = 0;
	B.host_baud = 57600;
	while (fgets(ln, sizeof ln, f)) {
		lineno++;
		char *p = ln + strspn(ln, " \t");
		if (*p == '#' || *p == '\n' || !*p) continue;
		p[strcspn(p, "\r\n")] = 0;
		char *end;
		double t_ms = strtod(p, &end);
		if (end == p || !isfinite(t_ms) || t_ms < 0) die("script line %d: expected '<t_ms> <command>'", lineno);
		while (*end == ' ' || *end == '\t') end++;
		run_until((avr_cycle_count_t)llround(t_ms * 1e-3 * (double)F_CPU));
		if (!strcmp(end, "open")) {
			host_opened();
		} else if (!strcmp(end, "close")) {
			host_closed();
			B.line_len = 0;
		} else if (!strncmp(end, "baud ", 5)) {
			B.host_baud = atoi(end + 5);
		} else if (!strncmp(end, "send ", 5)) {
			const char *h = end + 5;
			while (h[0] && h[1]) {
				int hi = hexval(h[0]), lo = hexval(h[1]);
				if (hi < 0 || lo < 0) die("script line %d: bad hex", lineno);
				if (B.host_open && B.inq_len < IN_QUEUE_MAX) B.inq[B.inq_len++] = (uint8_t)(hi << 4 | lo);
				h += 2;
			}
			feed_start();
		} else if (!strcmp(end, "end")) {
			break;
		} else if (!command(end)) {
			die("script line %d: unknown command '%s'", lineno, end);
		}
	}
	fclose(f);
	script_collect();
	fprintf(proto, "STATS ");
	write_stats(proto);
	fputc('\n', proto);
	fflush(proto);
	eeprom_save_if_changed();
}

/* ---- start-up ------------------------------------------------------------------------------- */

static void no_sleep(avr_t *avr, avr_cycle_count_t how_long) {
	(void)avr; (void)how_long;  /* pacing is ours: a sleeping AVR just skips to its next event */
}

static void on_signal(int sig) {
	(void)sig;
	stop_requested = 1;
}

static void usage(void) {
	fprintf(stderr,
		"usage: scale_board --elf SKETCH.elf [--bootloader-ms MS] [--rate 10|80]\n"
		"         [--eeprom FILE] [--control FIFO] [--force-n N] [--counts-per-g C]\n"
		"         [--offset-counts C] [--noise-counts C] [--channel-b-counts C] [--seed S]\n"
		"         [--drift-counts C] [--drift-tau-s S] [--spike-prob P]\n"
		"         [--boot-junk N] [--link PATH] [--script FILE [--trace 1]]\n");
	exit(2);
}

static void parse_args(int argc, char **argv, options_t *o) {
	memset(o, 0, sizeof *o);
	o->rate_sps = 80;
	o->bootloader_ms = BOOTLOADER_MS;
	o->counts_per_g = 696.0;
	o->offset_counts = 84000.0;
	o->drift_tau_s = 180.0;
	for (int i = 1; i < argc; i++) {
		const char *a = argv[i];
		const char *v = i + 1 < argc ? argv[i + 1] : NULL;
		if (!v) usage();
		char *end = NULL;
		i++;
		if (!strcmp(a, "--elf")) o->elf = v;
		else if (!strcmp(a, "--bootloader-ms")) o->bootloader_ms = strtod(v, &end);
		else if (!strcmp(a, "--eeprom")) o->eeprom_path = v;
		else if (!strcmp(a, "--control")) o->control_path = v;
		else if (!strcmp(a, "--script")) o->script_path = v;
		else if (!strcmp(a, "--trace")) trace = atoi(v);
		else if (!strcmp(a, "--link")) o->pty_link = v;
		else if (!strcmp(a, "--rate")) o->rate_sps = (int)strtol(v, &end, 10);
		else if (!strcmp(a, "--boot-junk")) o->boot_junk = (int)strtol(v, &end, 10);
		else if (!strcmp(a, "--seed")) o->seed = strtoull(v, &end, 10);
		else if (!strcmp(a, "--force-n")) o->force_n = strtod(v, &end);
		else if (!strcmp(a, "--counts-per-g")) o->counts_per_g = strtod(v, &end);
		else if (!strcmp(a, "--offset-counts")) o->offset_counts = strtod(v, &end);
		else if (!strcmp(a, "--noise-counts")) o->noise_counts = strtod(v, &end);
		else if (!strcmp(a, "--channel-b-counts")) o->channel_b_counts = strtod(v, &end);
		else if (!strcmp(a, "--drift-counts")) o->drift_counts = strtod(v, &end);
		else if (!strcmp(a, "--drift-tau-s")) o->drift_tau_s = strtod(v, &end);
		else if (!strcmp(a, "--spike-prob")) o->spike_prob = strtod(v, &end);
		else usage();
		if (end && *end) die("%s %s: not a number", a, v);
	}
	if (!o->elf) usage();
	if (o->rate_sps != 10 && o->rate_sps != 80) die("--rate %d: an HX711 runs at 10 or 80 samples/s", o->rate_sps);
	if (o->boot_junk < 0 || o->boot_junk > 16) die("--boot-junk %d: expected 0..16 bytes", o->boot_junk);
	if (!(o->bootloader_ms >= 0 && o->bootloader_ms <= 10000)) die("--bootloader-ms: expected 0..10000");
	if (!(o->spike_prob >= 0 && o->spike_prob <= 1)) die("--spike-prob: expected a probability in [0, 1]");
	if (!(o->drift_tau_s > 0) || !isfinite(o->drift_tau_s) || !isfinite(o->drift_counts))
		die("--drift-counts must be finite and --drift-tau-s positive");
	if (!isfinite(o->force_n) || !isfinite(o->counts_per_g) || !isfinite(o->offset_counts) ||
	    !isfinite(o->noise_counts) || o->noise_counts < 0 || !isfinite(o->channel_b_counts))
		die("the load and HX711 parameters must be finite (noise >= 0)");
}

int main(int argc, char **argv) {
	/* simavr prints on stdout; keep the real stdout for our own lines. */
	int out = dup(1);
	dup2(2, 1);
	proto = fdopen(out, "w");
	memset(&B, 0, sizeof B);
	B.master = -1;
	parse_args(argc, argv, &B.opt);
	rng_state ^= B.opt.seed * 0xD1B54A32D192ED03ULL;
	if (!rng_state) rng_state = 1;
	prctl(PR_SET_TIMERSLACK, 1000UL, 0, 0, 0);  /* sleeps end within ~1 us, not 50 */

	elf_firmware_t fw;
	memset(&fw, 0, sizeof fw);
	if (elf_read_firmware(B.opt.elf, &fw) != 0) die("cannot read the firmware %s", B.opt.elf);
	B.avr = avr_make_mcu_by_name("atmega328p");
	if (!B.avr) die("libsimavr has no atmega328p");
	avr_init(B.avr);
	B.avr->log = LOG_ERROR;
	fw.frequency = F_CPU;
	avr_load_firmware(B.avr, &fw);
	B.avr->frequency = F_CPU;
	B.avr->sleep = no_sleep;
	uint32_t flags = 0;
	avr_ioctl(B.avr, AVR_IOCTL_UART_GET_FLAGS('0'), &flags);
	flags &= ~(uint32_t)(AVR_UART_FLAG_STDIO | AVR_UART_FLAG_POLL_SLEEP);
	avr_ioctl(B.avr, AVR_IOCTL_UART_SET_FLAGS('0'), &flags);
	uart_fix_install();
	B.uart_in_irq = avr_io_getirq(B.avr, AVR_IOCTL_UART_GETIRQ('0'), UART_IRQ_INPUT);
	B.dout_irq = avr_io_getirq(B.avr, AVR_IOCTL_IOPORT_GETIRQ('D'), HX_PIN_DOUT);
	avr_irq_register_notify(avr_io_getirq(B.avr, AVR_IOCTL_IOPORT_GETIRQ('D'), HX_PIN_SCK), hx_sck_changed, NULL);

	memset(B.ee_saved, 0xFF, EEPROM_SIZE);  /* an erased EEPROM */
	if (B.opt.eeprom_path) {
		FILE *f = fopen(B.opt.eeprom_path, "rb");
		if (f) {
			uint8_t tmp[EEPROM_SIZE];
			if (fread(tmp, 1, EEPROM_SIZE, f) == EEPROM_SIZE) memcpy(B.ee_saved, tmp, EEPROM_SIZE);
			else fprintf(stderr, "scale_board: %s is not %d bytes: starting erased\n", B.opt.eeprom_path, EEPROM_SIZE);
			fclose(f);
		}
	}
	eeprom_set(B.ee_saved);

	B.hx.period = F_CPU / (avr_cycle_count_t)B.opt.rate_sps;
	B.hx.connected = 1;
	B.hx.dout = 1;
	hx_power_up(0);                         /* powered with the board */
	/* Power-on: the AVR starts (MCUSR.PORF), so optiboot hands over to the sketch at once. */
	B.avr->data[MCUSR_ADDR] = 1;
	hx_drive_dout(1);
	reschedule();

	if (B.opt.control_path) {
		control_fd = open(B.opt.control_path, O_RDWR | O_NONBLOCK);  /* RDWR: no EOF when writers leave */
		if (control_fd < 0) die("cannot open the control FIFO %s: %s", B.opt.control_path, strerror(errno));
	}
	struct sigaction sa;
	memset(&sa, 0, sizeof sa);
	sa.sa_handler = on_signal;
	sigaction(SIGINT, &sa, NULL);
	sigaction(SIGTERM, &sa, NULL);
	signal(SIGPIPE, SIG_IGN);

	if (B.opt.script_path) {
		B.script = 1;
		run_script();
	} else {
		run_pty();
	}
	if (B.avr->state == cpu_Crashed) {
		fprintf(stderr, "scale_board: the AVR crashed at pc 0x%04x\n", B.avr->pc);
		return 3;
	}
	if (B.opt.pty_link) unlink(B.opt.pty_link);
	return 0;
}
