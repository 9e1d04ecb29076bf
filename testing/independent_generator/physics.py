"""What the machine and the parts do to a recording, from physics and the data sheet.

Each function makes one cause the way the cause works, not the way a diagnosis would
model it; all act on the fine time grid (board.FINE_HZ), accelerations in g.

- mount: the sensor on a bracket, a uniform cantilever base-excited at its root. Its tip's
  absolute acceleration is the base's plus the first two bending modes' relative response,
  f2 = 6.27·f1 (a clamped-free beam), each mode weighted by its tip participation
  Γᵢφᵢ(L) = 1.566, −0.868 (Blevins, Formulas for natural frequency and mode shape, table
  8-1). The drive excites it as a shaker does: band-limited random acceleration while the
  axis moves (a belt, a screw, a motor's torque ripple).
- rail: a carriage on a rail whose height is not straight: its pitch θ(x) is the slope of a
  cubic height profile (a sag plus a twist along the travel); gravity reads g·sin θ(x).
- thermal: a board near the motor, a first-order body heated by the motor's copper losses
  (∝ force², ∝ a²) and friction (∝ |v|), cooling to ambient with time constant τ; the die
  follows the board with a lag of its own, and the part's zero-g offset moves with the
  die's temperature (data sheet: zero-g drift of the order of 2 mg/°C).
- misalignment and cross-axis sensitivity: each sense axis is turned by a small angle in
  the plane and responds ±2 % to the orthogonal axis (data sheet order).
- modulator nonlinearity: a quadratic and a cubic deviation (data sheet: ~0.2 % of full
  scale; a bad part several times that).
- saturation: an output stage whose supply lets it swing less than ±2 g, with a soft knee.
- servo: a controller's logged position is its command; the axis follows through its
  position loop (a second-order response), or the logger stamps the encoder late.
- bias wander: power-law (flicker to random-walk) noise of the zero-g level.
- link: a USB serial adapter that sends when its 62-byte buffer fills or its latency timer
  expires; the host stamps whole bursts at once; its clock is stepped by NTP.
- hum: mains ripple on the supply modulating the duty (50 Hz and its third harmonic).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.signal import bilinear, lfilter

from testing.independent_generator.board import FINE_HZ, UART_FRAME_S

# uniform cantilever, clamped-free: second bending mode over the first, and the tip's
# participation (Γᵢ·φᵢ at the tip) of the first two modes
CANTILEVER_F2_OVER_F1 = 6.267
CANTILEVER_TIP_PARTICIPATION = (1.566, -0.868)
USB_PACKET_BYTES = 62  # an FTDI-style adapter: 64-byte packet less 2 status bytes
FRAME_BYTES = 15


def _second_order_lowpass(x: np.ndarray, f_hz: float, zeta: float) -> np.ndarray:
    """ω²/(s² + 2ζωs + ω²) by the bilinear transform, from rest."""
    w = 2.0 * math.pi * f_hz
    b, a = bilinear([w * w], [1.0, 2 * zeta * w, w * w], FINE_HZ)
    return lfilter(b, a, x)


def cantilever_tip(base_g: np.ndarray, f1_hz: float, zeta: float) -> np.ndarray:
    """Absolute acceleration at the tip of a base-excited cantilever (two modes).

    The relative displacement of mode i obeys q̈ + 2ζωq̇ + ω²q = −a_base; the tip's
    absolute acceleration is a_base + Σ Γᵢφᵢ·q̈ᵢ, and q̈ᵢ = −a_base·s²/(s² + 2ζωs + ω²)
    = −a_base + a_base·(2ζωs + ω²)/(…); written with the low-pass form:
    q̈ᵢ = −a_base + lowpass_i(a_base) + 2ζ/ω·d/dt lowpass_i(a_base).
    """
    base = base_g - base_g[0]
    tip = base.copy()
    for ratio, weight in zip((1.0, CANTILEVER_F2_OVER_F1), CANTILEVER_TIP_PARTICIPATION, strict=True):
        f = f1_hz * ratio
        w = 2.0 * math.pi * f
        low = _second_order_lowpass(base, f, zeta)
        q_acc = -base + low + (2 * zeta / w) * np.gradient(low) * FINE_HZ
        tip = tip + weight * q_acc
    return tip + base_g[0]


def drive_vibration(moving: np.ndarray, rms_g: float, rng: np.random.Generator,
                    band_hz=(5.0, 400.0)) -> np.ndarray:
    """Band-limited random acceleration while the drive runs (a shaker's random test)."""
    n = moving.size
    spectrum = np.fft.rfft(rng.standard_normal(n))
    f = np.fft.rfftfreq(n, 1.0 / FINE_HZ)
    spectrum[(f < band_hz[0]) | (f > band_hz[1])] = 0.0
    noise = np.fft.irfft(spectrum, n)
    noise *= rms_g / max(float(np.std(noise)), 1e-30)
    # the drive starts and stops over ~20 ms, not in one sample
    ramp = np.convolve(moving.astype(float), np.ones(400) / 400.0, mode="same")
    return noise * ramp


def rail_pitch_rad(x_m: np.ndarray, slope_per_m: float, curvature_per_m2: float) -> np.ndarray:
    """Pitch of a carriage on a rail of cubic height h(x): θ = h'(x) = κ1·x + κ2·x²."""
    return slope_per_m * x_m + curvature_per_m2 * x_m**2


def machine_heat(acc_mps2: np.ndarray, vel_mps: np.ndarray) -> np.ndarray:
    """Relative heating power of the drive: copper losses ∝ force² ∝ a², friction ∝ |v|
    (both normalised to the paper's motion: 10 m/s², 1 m/s)."""
    return (acc_mps2 / 10.0) ** 2 + 0.5 * np.abs(vel_mps) / 1.0


def first_order(x: np.ndarray, tau_s: float, start: float) -> np.ndarray:
    """τ·ẏ = x − y, exact for a piecewise-constant input on the fine grid."""
    phi = math.exp(-1.0 / (FINE_HZ * tau_s))
    y, _ = lfilter([1 - phi], [1.0, -phi], x, zi=[phi * start])
    return y


def soft_saturation(y_g: np.ndarray, upper_g: float, lower_g: float, knee_g: float) -> np.ndarray:
    """An output stage that runs out of supply: linear inside, flat at its limits, with a
    smooth knee of width knee_g (a softplus on each side)."""
    top = upper_g - knee_g * np.logaddexp(0.0, (upper_g - y_g) / knee_g)
    return lower_g + knee_g * np.logaddexp(0.0, (top - lower_g) / knee_g)


def servo_follow(command: np.ndarray, lag_s: float, zeta: float = 0.7) -> np.ndarray:
    """The axis following its command through a position loop: ωn²/(s² + 2ζωn s + ωn²),
    whose low-frequency lag is 2ζ/ωn."""
    f = 2 * zeta / lag_s / (2 * math.pi)
    return _second_order_lowpass(command - command[0], f, zeta) + command[0]


def power_law_wander(n: int, alpha: float, change_rms_g: float, span_s: float,
                     rng: np.random.Generator) -> np.ndarray:
    """Noise with spectrum ∝ 1/f^α (α = 1 flicker, 2 random walk) on the fine grid,
    scaled so that its change over span_s has the given rms."""
    spectrum = np.fft.rfft(rng.standard_normal(n))
    f = np.fft.rfftfreq(n, 1.0 / FINE_HZ)
    f[0] = f[1]
    spectrum *= f ** (-alpha / 2.0)
    spectrum[0] = 0.0
    x = np.fft.irfft(spectrum, n)
    lag = min(int(span_s * FINE_HZ), n - 1)
    change = float(np.sqrt(np.mean((x[lag:] - x[:-lag]) ** 2))) if lag > 0 else 1.0
    return x * change_rms_g / max(change, 1e-30)


def usb_adapter_arrivals(end_s: np.ndarray, latency_timer_s: float, rng: np.random.Generator,
                         ntp_step_s: float = 0.0) -> np.ndarray:
    """Host stamps through a buffering USB serial adapter.

    Bytes enter the adapter's buffer as the UART delivers them; it sends a packet when 62
    bytes are waiting or its latency timer expires since the last packet. The host's
    reader wakes up after a scheduling delay (mostly ~0.3 ms, 1 % of wake-ups 5–20 ms late)
    and stamps every complete frame of what it read with the same clock reading plus the
    few µs of parsing each. An NTP correction steps the host clock back once (ntp_step_s)."""
    done = end_s + UART_FRAME_S  # the frame's last byte in the adapter
    sent = np.empty_like(done)
    buffered_bytes = 0
    timer_start = float(done[0])
    first_unsent = 0
    for i, t in enumerate(done):
        if buffered_bytes > 0 and timer_start + latency_timer_s <= t:
            # the timer expired before this frame was complete: what waits leaves then
            sent[first_unsent:i] = timer_start + latency_timer_s
            first_unsent, buffered_bytes = i, 0
        if buffered_bytes == 0:
            timer_start = float(t)
        buffered_bytes += FRAME_BYTES
        if buffered_bytes >= USB_PACKET_BYTES:
            # a full packet leaves now; this frame's last bytes wait for the next one
            sent[first_unsent:i] = t
            first_unsent, buffered_bytes, timer_start = i, buffered_bytes - USB_PACKET_BYTES, float(t)
    sent[first_unsent:] = max(timer_start + latency_timer_s, float(done[-1]))
    packets, packet_of = np.unique(sent, return_inverse=True)
    wake = rng.exponential(0.3e-3, packets.size)
    late = rng.random(packets.size) < 0.01
    wake[late] += rng.uniform(5e-3, 20e-3, int(late.sum()))
    # one reader: a packet is read after the one before it; every frame in it gets the
    # read's clock value plus the few µs of parsing each
    read = np.maximum.accumulate(packets + 1e-3 + wake)
    first_of_packet = np.searchsorted(packet_of, np.arange(packets.size))
    within = np.arange(done.size) - first_of_packet[packet_of]
    # the next read starts after the last frame of the one before was parsed
    stamp = np.maximum.accumulate(read[packet_of] + within * rng.uniform(2e-6, 8e-6))
    if ntp_step_s > 0:
        k = int(rng.integers(done.size // 4, 3 * done.size // 4))
        stamp[k:] -= ntp_step_s
    return stamp


def mains_ripple(t_s: np.ndarray, amp_g: float, f_hz: float, third: float, phase: float) -> np.ndarray:
    """Supply ripple at the mains frequency and its third harmonic (a rectifier's)."""
    w = 2 * math.pi * f_hz
    return amp_g * (np.sin(w * t_s + phase) + third * np.sin(3 * w * t_s + 2 * phase))
