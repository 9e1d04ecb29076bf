/* The ADXL202 board: duty-cycle timing on an 8052 and the frames of protocol version 1.
 *
 * Part: an 8052-class core (three timers), 11.0592 MHz, 12 clocks per machine cycle, so
 * every timer counts 921 600 ticks/s. The contract is docs/board-protocol.md.
 *
 * Who does what (the why is in docs/board-link.md, "The firmware"):
 *   Timer 2  the UART's baud generator: RCAP2 = 0xFFFD gives 11.0592 MHz / (32 * 3) =
 *            115 200 baud, which Timer 1 cannot make at this crystal (57 600 at most).
 *   Timer 0  gated by INT0 (P3.2 = the ADXL202's XOUT): counts only while X is high, so
 *            at X's falling edge it holds T1x, latched by the hardware — the interrupt can
 *            read it late without error.
 *   Timer 1  the same for Y on INT1 (P3.3). Every T2_EVERY_PERIODS periods it runs ungated
 *            for T2_SPAN_PERIODS periods from one Y falling edge to another: that is the
 *            sum of as many T2 (no timer is left to time T2 on every period). The Y samples
 *            of those periods carry flag bit 1 (Y not measured).
 * A period's sample is sent when both of its falling edges were seen. The rising edges of
 * XOUT and YOUT are common (the ADXL202 starts both duty cycles together), so an input pin
 * that is still high at the other axis's falling edge has its fall of this period to come.
 * An axis whose fall does not come before the other axis's next one timed out: the sample
 * goes out with its flag, so does the axis's first capture after it (its high time may have
 * begun mid-period), and the period after that is measured again (a stuck-low input leaves
 * its gated timer stopped; a stuck-high one ends with a count longer than T2).
 */
#include <8052.h>
#include <stdint.h>

#include "crc16_table.h"

#ifdef BUSY_IDLE
#define SLEEP() do { } while (0)
#else
#define SLEEP() (PCON |= IDL)
#endif

#define FW_MAJOR 1
#define FW_MINOR 1
#define TICK_HZ 921600UL /* 11.0592 MHz / 12 */

#define SYNC1 0xA5
#define SYNC2 0x5A
#define TYPE_SAMPLE 0x01
#define TYPE_STATUS 0x02
#define TYPE_HELLO 0x03
#define FLAG_X_TIMED_OUT 0x01
#define FLAG_Y_TIMED_OUT 0x02
#define TEMP_NO_SENSOR 0x8000

/* T2 is timed over T2_SPAN_PERIODS periods (a power of two: the mean is a shift) so that
 * the interrupt latency at its two ends, a few machine cycles, is divided by the span;
 * 32 periods of the 2 ms default fit the 16-bit timer (59 300 ticks), a longer T2 wraps
 * it once, which the overflow flag counts. Every T2_EVERY_PERIODS periods (about 2 s):
 * T2 is set by RSET and follows only its temperature (ADXL202 data sheet). */
#define T2_SPAN_PERIODS 32
#define T2_SPAN_SHIFT 5
#define T2_EVERY_PERIODS 1024

/* TMOD: both timers mode 1 (16 bit); GATE so each counts only while its INT pin is high */
#define TMOD_BOTH_GATED 0x99
#define TMOD_Y_FREE 0x19

static __code const uint8_t CRC_HI[256] = {CRC_TABLE(CRC_HI_OF)};
static __code const uint8_t CRC_LO[256] = {CRC_TABLE(CRC_LO_OF)};

/* --- the UART: a ring of bytes, sent by the serial interrupt ---------------------- */
#define TX_SIZE 64 /* a power of two; three SAMPLE frames and a STATUS */
#define TX_MASK (TX_SIZE - 1)
static __idata uint8_t tx_buf[TX_SIZE];
static volatile uint8_t tx_head; /* written by main */
static volatile uint8_t tx_tail; /* written by the serial interrupt */
static volatile __bit tx_busy;

void serial_isr(void) __interrupt(4) __using(2)
{
    if (TI) {
        TI = 0;
        if (tx_tail != tx_head) {
            SBUF = tx_buf[tx_tail];
            tx_tail = (tx_tail + 1) & TX_MASK;
        } else {
            tx_busy = 0;
        }
    }
}

/* --- the samples: a queue from the edge interrupts to the main loop -------------- */
#define Q_SIZE 4
#define Q_MASK (Q_SIZE - 1)
static __idata uint16_t q_t1x[Q_SIZE];
static __idata uint16_t q_t1y[Q_SIZE];
static __idata uint8_t q_flags[Q_SIZE];
static __idata uint16_t q_seq[Q_SIZE];
static volatile uint8_t q_head; /* written by the edge interrupts */
static volatile uint8_t q_tail; /* written by main */
static uint16_t next_seq;       /* seq of the next sample; one per period, sent or not */
static volatile __bit running;  /* samples are made once T2 is known */
/* Set by an interrupt that left work for the main loop. Every interrupt (15 serial ones
 * per sample) ends the CPU's idle mode; one bit test sends it back to sleep. */
static volatile __bit work;

/* Both edge interrupts run at the same (high) priority, so neither interrupts the other:
 * the pairing below needs no locking. */
#define EMIT(t1x_, t1y_, flags_)                                                     \
    do {                                                                             \
        if (running) {                                                               \
            uint8_t slot_ = q_head;                                                  \
            uint8_t after_ = (slot_ + 1) & Q_MASK;                                   \
            if (after_ != q_tail) { /* a full queue loses the sample; seq tells */   \
                q_t1x[slot_] = (t1x_);                                               \
                q_t1y[slot_] = (t1y_);                                               \
                q_flags[slot_] = (flags_);                                           \
                q_seq[slot_] = next_seq;                                             \
                q_head = after_;                                                     \
                work = 1;                                                            \
            }                                                                        \
            next_seq++;                                                              \
        }                                                                            \
    } while (0)

/* one axis's last capture, waiting for the other axis's fall of the same period */
static uint16_t x_t1, y_t1;
static uint8_t x_flag, y_flag; /* its timed-out bit, or 0 */
static volatile __bit x_done, y_done;
/* An axis that timed out: its next fall may end a high time that began mid-period (an
 * input stuck low that comes back while the waveform is high), which no count can tell
 * from a small duty cycle — so that capture is flagged too, and the one after is good. */
static __bit x_recovering, y_recovering;

/* T2 timing on Timer 1 */
#define T2_GATED 0
#define T2_START 1
#define T2_RUN 2
#define T2_STOP 3
static uint8_t t2_phase = T2_GATED;
static uint16_t t2_countdown = 1; /* the first measurement starts at the first Y fall */
static uint8_t t2_left;
static uint16_t t2_start_count;
static uint8_t y_tmod = TMOD_BOTH_GATED;
static volatile uint16_t t2_sum_lo; /* the last measurement: ticks in T2_SPAN_PERIODS */
static volatile __bit t2_sum_wrapped;
static volatile __bit t2_fresh;
/* X falls counted, so that a T2 span in which Y missed a fall (a stuck Y: the span then
 * holds more than T2_SPAN_PERIODS periods) is seen and dropped */
static uint8_t x_falls, x_falls_at_t2_start, x_span;
/* Set when Y fell while the X interrupt ran: the Y interrupt that follows starts late, by
 * up to the X interrupt's length — too late to start or end a T2 span (a 32-period span
 * whose one end is 60 cycles late is 2 ticks off per period). Such a span is not started
 * (tried again at the next Y fall) or not used (tried again T2_RETRY_PERIODS later). */
static volatile __bit y_delayed;
#define T2_RETRY_PERIODS 64

void x_fall_isr(void) __interrupt(0) __using(1)
{
    uint8_t lo = TL0;
    uint8_t hi = TH0;
    /* gated: stopped while X is low, so clearing it here loses nothing */
    TL0 = 0;
    TH0 = 0;
    if (x_done) /* our last fall met no Y fall: Y timed out in that period */
    {
        EMIT(x_t1, 0, x_flag | FLAG_Y_TIMED_OUT);
        y_recovering = 1;
    }
    x_t1 = ((uint16_t)hi << 8) | lo;
    x_flag = (TF0 || x_recovering) ? FLAG_X_TIMED_OUT : 0; /* TF0: high for over 65 535 ticks */
    x_recovering = 0;
    TF0 = 0;
    x_done = 1;
    x_falls++;
    if (y_done) {
        if (!P3_3) { /* Y fell in this period too: the pair is complete */
            EMIT(x_t1, y_t1, x_flag | y_flag);
            x_done = 0;
        } else { /* Y's capture is from a period whose X fall never came */
            EMIT(0, y_t1, FLAG_X_TIMED_OUT | y_flag);
            x_flag = FLAG_X_TIMED_OUT; /* so this fall is the first after a timeout */
        }
        y_done = 0;
    }
    if (IE1) /* Y fell meanwhile: its interrupt waits for this one to end */
        y_delayed = 1;
}

void y_fall_isr(void) __interrupt(2) __using(1)
{
    uint8_t lo = TL1;
    uint8_t hi = TH1;
    /* The same instructions at every entry, so this write falls at the same delay after
     * each Y falling edge: starting and stopping the T2 span here cancels that delay. */
    TMOD = y_tmod;
    if (y_done) /* our last fall met no X fall: X timed out in that period */
    {
        EMIT(0, y_t1, FLAG_X_TIMED_OUT | y_flag);
        x_recovering = 1;
    }
    y_t1 = ((uint16_t)hi << 8) | lo;
    y_flag = (TF1 || y_recovering) ? FLAG_Y_TIMED_OUT : 0;
    y_recovering = 0;
    switch (t2_phase) {
    case T2_GATED:
        TL1 = 0;
        TH1 = 0;
        TF1 = 0;
        if (--t2_countdown == 0) {
            y_tmod = TMOD_Y_FREE;
            t2_phase = T2_START;
        }
        break;
    case T2_START: /* Timer 1 now runs on from this period's high time, read above */
        if (y_delayed) { /* not from a late start: gated again, try at the next fall */
            TMOD = TMOD_BOTH_GATED;
            TL1 = 0;
            TH1 = 0;
            TF1 = 0;
            break;
        }
        t2_start_count = y_t1;
        x_falls_at_t2_start = x_falls;
        TF1 = 0;
        t2_left = T2_SPAN_PERIODS - 1;
        t2_phase = T2_RUN;
        break;
    case T2_RUN:
        y_flag = FLAG_Y_TIMED_OUT; /* this period's high time was not timed */
        if (--t2_left == 0) {
            y_tmod = TMOD_BOTH_GATED;
            t2_phase = T2_STOP;
        }
        break;
    default: /* T2_STOP: gated again with Y low, Timer 1 stopped at the write above */
        y_flag = FLAG_Y_TIMED_OUT;
        /* As many X falls as Y falls in the span (one more or less: X's fall may cross
         * Y's at either end), else a stuck input lengthened it: dropped, T2 kept. */
        x_span = x_falls - x_falls_at_t2_start;
        t2_countdown = T2_RETRY_PERIODS;
        if (!y_delayed && x_span >= T2_SPAN_PERIODS - 1 && x_span <= T2_SPAN_PERIODS + 1) {
            t2_countdown = T2_EVERY_PERIODS;
            t2_sum_lo = (((uint16_t)TH1 << 8) | TL1) - t2_start_count;
            t2_sum_wrapped = TF1 ^ (((uint16_t)TH1 << 8 | TL1) < t2_start_count);
            t2_fresh = 1;
            work = 1;
        }
        TL1 = 0;
        TH1 = 0;
        TF1 = 0;
        t2_phase = T2_GATED;
        break;
    }
    y_delayed = 0;
    y_done = 1;
    if (x_done) {
        if (!P3_2) { /* X fell in this period too */
            EMIT(x_t1, y_t1, x_flag | y_flag);
            y_done = 0;
        } else { /* X's capture is from a period whose Y fall never came */
            EMIT(x_t1, 0, x_flag | FLAG_Y_TIMED_OUT);
            y_flag = FLAG_Y_TIMED_OUT; /* so this fall is the first after a timeout */
        }
        x_done = 0;
    }
}

/* --- frames ---------------------------------------------------------------------- */
/* A frame is written straight into the ring through one pointer, each byte folded into
 * the CRC on the way (inline: a call per byte would cost a third of the frame's time). */
static uint8_t crc_hi, crc_lo;
static __idata uint8_t *tx_put;

#define PUT_RAW(b)                          \
    do {                                    \
        *tx_put = (b);                      \
        if (++tx_put == tx_buf + TX_SIZE)   \
            tx_put = tx_buf;                \
    } while (0)
#define PUT(b)                                  \
    do {                                        \
        uint8_t v_ = (b);                       \
        uint8_t i_ = crc_hi ^ v_;               \
        crc_hi = crc_lo ^ CRC_HI[i_];           \
        crc_lo = CRC_LO[i_];                    \
        PUT_RAW(v_);                            \
    } while (0)
/* the CRC register after a SAMPLE frame's type and length bytes: the same for every
 * SAMPLE, so computed once at start-up */
static uint16_t crc_after_sample_header;

static uint16_t crc_after_header(uint8_t type, uint8_t length)
{
    uint8_t i = 0xFF ^ type;
    crc_hi = 0xFF ^ CRC_HI[i];
    crc_lo = CRC_LO[i];
    i = crc_hi ^ length;
    crc_hi = crc_lo ^ CRC_HI[i];
    crc_lo = CRC_LO[i];
    return ((uint16_t)crc_hi << 8) | crc_lo;
}

static void frame_begin(uint8_t type, uint8_t length, uint16_t crc_after_header)
{
    /* wait for room for the whole frame (the serial interrupt empties the ring) */
    while (((tx_tail - tx_head - 1) & TX_MASK) < (uint8_t)(length + 6))
        SLEEP();
    tx_put = tx_buf + tx_head;
    PUT_RAW(SYNC1);
    PUT_RAW(SYNC2);
    PUT_RAW(type);
    PUT_RAW(length);
    crc_hi = crc_after_header >> 8;
    crc_lo = crc_after_header & 0xFF;
}

static void frame_end(void)
{
    uint8_t hi = crc_hi, lo = crc_lo;
    PUT_RAW(hi);
    PUT_RAW(lo);
    tx_head = tx_put - tx_buf; /* one write: the serial interrupt sees the whole frame */
    if (!tx_busy) {
        tx_busy = 1;
        TI = 1; /* the serial interrupt sends the first byte */
    }
}

static uint16_t last_seq = 0xFFFF;
static uint32_t uptime_s;

static void send_report(uint8_t type)
{
    frame_begin(type, 14, crc_after_header(type, 14));
    PUT(last_seq >> 8);
    PUT(last_seq & 0xFF);
    PUT(uptime_s >> 24);
    PUT((uptime_s >> 16) & 0xFF);
    PUT((uptime_s >> 8) & 0xFF);
    PUT(uptime_s & 0xFF);
    PUT(TICK_HZ >> 24);
    PUT((TICK_HZ >> 16) & 0xFF);
    PUT((TICK_HZ >> 8) & 0xFF);
    PUT(TICK_HZ & 0xFF);
    PUT(TEMP_NO_SENSOR >> 8);
    PUT(TEMP_NO_SENSOR & 0xFF);
    PUT(FW_MAJOR);
    PUT(FW_MINOR);
    frame_end();
}

/* T2 per sample: the span's mean, its remainder spread over the periods so that the sum
 * of the T2 sent — the board's clock — keeps the measured rate to the tick */
static uint16_t t2_base;
static uint8_t t2_remainder, t2_spread;
static uint32_t tick_in_second;
static __bit status_due;

static void take_t2_measurement(void)
{
    uint16_t sum;
    __bit wrapped;
    EA = 0;
    sum = t2_sum_lo;
    wrapped = t2_sum_wrapped;
    t2_fresh = 0;
    EA = 1;
    t2_base = (sum >> T2_SPAN_SHIFT) | (wrapped ? (uint16_t)(0x10000UL >> T2_SPAN_SHIFT) : 0);
    t2_remainder = sum & (T2_SPAN_PERIODS - 1);
}

static void send_sample(void)
{
    uint8_t slot = q_tail;
    uint16_t t1x = q_t1x[slot], t1y = q_t1y[slot], seq = q_seq[slot];
    uint8_t flags = q_flags[slot];
    uint16_t t2 = t2_base;
    q_tail = (slot + 1) & Q_MASK;
    t2_spread += t2_remainder;
    if (t2_spread >= T2_SPAN_PERIODS) {
        t2_spread -= T2_SPAN_PERIODS;
        t2++;
    }
    /* a capture longer than the period: the falling edge did not come in time */
    if (t1x > t2)
        flags |= FLAG_X_TIMED_OUT;
    if (t1y > t2)
        flags |= FLAG_Y_TIMED_OUT;
    frame_begin(TYPE_SAMPLE, 9, crc_after_sample_header);
    PUT(seq >> 8);
    PUT(seq & 0xFF);
    PUT(t1x >> 8);
    PUT(t1x & 0xFF);
    PUT(t1y >> 8);
    PUT(t1y & 0xFF);
    PUT(t2 >> 8);
    PUT(t2 & 0xFF);
    PUT(flags);
    frame_end();
    last_seq = seq;
    /* the board's clock is the sum of the periods (the protocol's sample time) */
    tick_in_second += t2;
    if (tick_in_second >= TICK_HZ) {
        tick_in_second -= TICK_HZ;
        uptime_s++;
        status_due = 1;
    }
}

void main(void)
{
    TMOD = TMOD_BOTH_GATED;
    TH0 = TL0 = TH1 = TL1 = 0;
    /* UART mode 1 (8N1), Timer 2 as its baud generator */
    SCON = 0x40;
    RCAP2H = 0xFF;
    RCAP2L = 0xFD;
    TH2 = 0xFF;
    TL2 = 0xFD;
    T2CON = 0x34; /* RCLK | TCLK | TR2 */
    IT0 = 1;      /* falling edges */
    IT1 = 1;
    PX0 = 1; /* the edges above the UART: the serial interrupt never delays a T2 span */
    PX1 = 1;
    TR0 = 1;
    TR1 = 1;
    EX0 = 1;
    EX1 = 1;
    ES = 1;
    EA = 1;
    crc_after_sample_header = crc_after_header(TYPE_SAMPLE, 9);
    send_report(TYPE_HELLO);
    while (!t2_fresh)
        SLEEP();
    take_t2_measurement();
    running = 1;
    for (;;) {
        while (!work)
            SLEEP(); /* until the next interrupt: the idle share is this time */
        work = 0;
        while (q_tail != q_head)
            send_sample();
        if (status_due) {
            status_due = 0;
            send_report(TYPE_STATUS);
        }
        if (t2_fresh)
            take_t2_measurement();
    }
}
