"""Which status bits the gateway publishes, from what it knows — a pure function.

Kept apart from the supervisor so every rule is tested on its own.
"""
from __future__ import annotations

from dataclasses import dataclass

from drivers.published_values import NOT_USABLE_BITS, StatusBits, flag_word

# Events (a board reset, lost samples, a config reload) stay visible this long, so a
# PLC polling once a second cannot miss them.
EVENT_HOLD_S = 10.0


@dataclass(slots=True)  # not frozen: built for every published snapshot, and frozen init is slow
class GatewayCondition:
    now_s: float
    have_estimate: bool
    port_open: bool
    last_sample_s: float | None  # monotonic time the newest sample arrived
    last_byte_s: float | None
    stale_after_s: float
    lost_after_s: float
    referenced: bool
    standstill: bool = False
    estimator_fault: bool = False
    holding: bool = False
    axis_invalid: bool = False
    saturated_until_s: float = -1.0
    board_reset_at_s: float | None = None
    samples_lost_at_s: float | None = None
    config_reloaded_at_s: float | None = None
    bias_estimating: bool = False
    untrusted: bool = False  # the estimator cannot tell a cruise from a stop now



@dataclass(slots=True)  # not frozen: the supervisor keeps one and sets its fields at each snapshot read
class LinkHealth:
    """What the supervisor knows of the wires, for the status bits and counters: a live
    record (the supervisor's one, brought up to date before each snapshot); read it when
    given, keep no reference."""

    port_open: bool
    last_byte_s: float | None
    stale_after_s: float
    lost_after_s: float
    config_reloaded_at_s: float | None = None
    can_send_errors: int = 0
    can_refused_commands: int = 0
    simulated: bool = False  # the board is the built-in emulated one
    mqtt_down: bool = False  # the MQTT edge node is on but not connected to its broker
    mqtt_dropped: int = 0  # DDATA the edge node dropped (its queue full)


_VALID = int(StatusBits.VALID)
_BOARD_LOST = int(StatusBits.BOARD_LOST)
_STALE = int(StatusBits.STALE)
_NOT_REFERENCED = int(StatusBits.NOT_REFERENCED)
_STANDSTILL = int(StatusBits.STANDSTILL)
_ESTIMATOR_FAULT = int(StatusBits.ESTIMATOR_FAULT)
_HOLDING = int(StatusBits.HOLDING)
_AXIS_INVALID = int(StatusBits.AXIS_INVALID)
_SATURATED = int(StatusBits.SATURATED)
_BOARD_RESET = int(StatusBits.BOARD_RESET)
_SAMPLES_LOST = int(StatusBits.SAMPLES_LOST)
_CONFIG_RELOADED = int(StatusBits.CONFIG_RELOADED)
_BIAS_ESTIMATING = int(StatusBits.BIAS_ESTIMATING)
_UNTRUSTED = int(StatusBits.POSITION_UNTRUSTED)
_UNUSABLE = int(NOT_USABLE_BITS)


def status_bits(c: GatewayCondition) -> StatusBits:
    # plain ints while composing: IntFlag arithmetic costs µs per operation, and this
    # runs for every sample
    bits = 0
    byte_age = None if c.last_byte_s is None else c.now_s - c.last_byte_s
    if not c.port_open or byte_age is None or byte_age > c.lost_after_s:
        bits |= _BOARD_LOST
    sample_age = None if c.last_sample_s is None else c.now_s - c.last_sample_s
    if sample_age is None or sample_age > c.stale_after_s:
        bits |= _STALE
    if not c.referenced:
        bits |= _NOT_REFERENCED
    if c.standstill:
        bits |= _STANDSTILL
    if c.estimator_fault:
        bits |= _ESTIMATOR_FAULT
    if c.holding:
        bits |= _HOLDING
    if c.axis_invalid:
        bits |= _AXIS_INVALID
    if c.now_s < c.saturated_until_s:
        bits |= _SATURATED
    # (events held EVENT_HOLD_S; written out, not a helper: this runs for every snapshot)
    now = c.now_s
    if c.board_reset_at_s is not None and now - c.board_reset_at_s < EVENT_HOLD_S:
        bits |= _BOARD_RESET
    if c.samples_lost_at_s is not None and now - c.samples_lost_at_s < EVENT_HOLD_S:
        bits |= _SAMPLES_LOST
    if c.config_reloaded_at_s is not None and now - c.config_reloaded_at_s < EVENT_HOLD_S:
        bits |= _CONFIG_RELOADED
    if c.bias_estimating:
        bits |= _BIAS_ESTIMATING
    if c.untrusted:
        bits |= _UNTRUSTED
    if c.have_estimate and not bits & _UNUSABLE:
        bits |= _VALID
    return flag_word(StatusBits, bits)
