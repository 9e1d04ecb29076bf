

from drivers.published_values import StatusBits
from gateway.daemon.status_flags import EVENT_HOLD_S, GatewayCondition, status_bits


def cond(**kw):
    base = dict(now_s=100.0, have_estimate=True, port_open=True, last_sample_s=99.999, last_byte_s=99.999,
                stale_after_s=0.1, lost_after_s=2.0, referenced=True)
    base.update(kw)
    return GatewayCondition(**base)


def test_fresh_referenced_estimate_is_valid_and_nothing_else():
    assert status_bits(cond()) == StatusBits.VALID


def test_stale_then_board_lost_clear_valid():
    assert status_bits(cond(last_sample_s=99.5)) == StatusBits.STALE
    bits = status_bits(cond(last_sample_s=97.0, last_byte_s=97.0))
    assert bits == StatusBits.STALE | StatusBits.BOARD_LOST
    bits = status_bits(cond(port_open=False))
    assert StatusBits.BOARD_LOST in bits and StatusBits.VALID not in bits


def test_start_up_before_any_sample_is_lost_stale_and_not_referenced():
    bits = status_bits(cond(have_estimate=False, last_sample_s=None, last_byte_s=None, referenced=False))
    assert bits == StatusBits.STALE | StatusBits.BOARD_LOST | StatusBits.NOT_REFERENCED


def test_not_referenced_does_not_clear_valid_but_faults_do():
    assert status_bits(cond(referenced=False)) == StatusBits.VALID | StatusBits.NOT_REFERENCED
    for kw, bit in (("estimator_fault", StatusBits.ESTIMATOR_FAULT), ("holding", StatusBits.HOLDING),
                    ("axis_invalid", StatusBits.AXIS_INVALID)):
        assert status_bits(cond(**{kw: True})) == bit


def test_events_stay_visible_for_the_hold_time():
    bits = status_bits(cond(board_reset_at_s=95.0, samples_lost_at_s=99.0, config_reloaded_at_s=91.0,
                            saturated_until_s=100.5))
    assert bits == (StatusBits.VALID | StatusBits.BOARD_RESET | StatusBits.SAMPLES_LOST
                    | StatusBits.CONFIG_RELOADED | StatusBits.SATURATED)
    later = 100.0 + EVENT_HOLD_S
    assert status_bits(cond(now_s=later, last_sample_s=later, last_byte_s=later, board_reset_at_s=95.0,
                            saturated_until_s=100.5)) == StatusBits.VALID
