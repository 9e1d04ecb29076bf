"""The daemon across a real loss of samples: the emulated board's line cut
(`adxlgw emulate --cut-after S --cut-for S`) loses what the board writes meanwhile while
its seq runs on, so the daemon judges the gap by the board's seq and period
(sample_loop.OUTAGE_S), end to end through the real daemon, its Modbus server and the
emulated board on a pty. No wall-clock asserts: every wait polls the status with a
generous limit, the board's timeline is its own clock, the board seeded."""
import asyncio
from dataclasses import replace

import pytest
from pymodbus.client import AsyncModbusTcpClient

from drivers.published_values import StatusBits
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.motion_profiles import StrokeSettings
from gateway.core.sensor_model import BOARD_SENSOR, SensorParams
from gateway.daemon.sample_loop import OUTAGE_S
from tests.daemon_helpers import Emulator, gateway_config, read_inputs, running_gateway, wait_for

pytestmark = pytest.mark.slow

# the emulated board's sample period: T2 = RSET / 125 MΩ with the board's RSET and the
# part's T2 error (adxlgw emulate's defaults)
BOARD_PERIOD_S = BOARD_SENSOR.t2_s
# the emulated axis strokes between 0 and this (the paper's 30 cm)
STROKE_M = StrokeSettings().stroke_m
# at rest this long before the first stroke: the estimate is VALID long before the cut
REST_S = 4.0
# the axis's travel as its integrator would configure it: the stroke with 0.2 m to spare
TRAVEL_M = [-0.2, STROKE_M + 0.2]
# with the velocity lost, a quiet stretch this long is a stop: no cruise at the speed floor
# lasts longer within the travel (EstimatorSettings.quiet_stop_s)
QUIET_STOP_S = replace(from_sensor_model(SensorParams()), travel_span_m=TRAVEL_M[1] - TRAVEL_M[0]).quiet_stop_s


def lost_in(cut_s: float) -> int:
    return round(cut_s / BOARD_PERIOD_S)


async def with_gateway(tmp_path, emulator_args, body) -> None:
    board = Emulator(tmp_path, "--seed", "21", "--rest-s", f"{REST_S:g}", *emulator_args)
    cfg = gateway_config(tmp_path, str(board.link), estimator={"start_at_rest": True, "travel_m": TRAVEL_M})
    try:
        async with running_gateway(cfg) as gw:
            client = AsyncModbusTcpClient("127.0.0.1", port=gw.modbus.tcp_port)
            await client.connect()
            try:
                await body(gw, client)
            finally:
                client.close()
    finally:
        board.stop()


def status(gw) -> StatusBits:
    return gw.fresh_values().status


async def valid_before_the_cut(gw) -> None:
    await wait_for(lambda: StatusBits.VALID in status(gw) or gw.fresh_values().lost_samples, 30,
                   what="VALID or a loss")
    assert gw.fresh_values().lost_samples == 0, "the line was cut before the estimate was VALID"


def test_a_cut_longer_than_an_outage_starts_over_untrusted_until_a_stop_is_seen(tmp_path):
    """The line is cut for 4 × OUTAGE_S across the first stroke: the axis moves 0.3 m
    unseen. The daemon must not go on as if nothing happened: the estimator starts over at
    the gap — POSITION_UNTRUSTED, not VALID, the loss counted on the wire — and is VALID
    again only after a stop seen on evidence. After an outage the velocity is unknown, and
    a quiet stretch is a stop or a cruise until it outlasts any cruise the travel allows
    (QUIET_STOP_S); the dwells here outlast it, so the board's next stroke ends at a stop
    the estimator can decide."""
    cut_s = 4 * OUTAGE_S
    dwell_s = QUIET_STOP_S + 3.0
    # from 0.2 s before the first stroke (0.4 s long) to well after it
    args = ["--strokes", "2", "--dwell-s", f"{dwell_s:g}",
            "--cut-after", f"{REST_S - 0.2:g}", "--cut-for", f"{cut_s:g}"]

    async def body(gw, client):
        await valid_before_the_cut(gw)
        await wait_for(lambda: gw.fresh_values().lost_samples > 0, 30, what="the cut's samples lost")
        regs = await read_inputs(client)
        after = StatusBits(regs["STATUS"])
        assert StatusBits.POSITION_UNTRUSTED in after and StatusBits.VALID not in after, after
        assert StatusBits.SAMPLES_LOST in after and StatusBits.NOT_REFERENCED in after, after
        assert regs["LOST_SAMPLES"] == pytest.approx(lost_in(cut_s), abs=2)
        assert gw.intake.events.outage_at_s is not None
        # VALID again once a stop is seen on evidence (the whole timeline: ~20 s of board time)
        await wait_for(lambda: StatusBits.VALID in status(gw), 90, what="VALID again")
        regs = await read_inputs(client)
        assert StatusBits.NOT_REFERENCED in StatusBits(regs["STATUS"])  # until a tare
        # never confidently wrong: wherever on its stroke the axis is, 3σ reaches it (the
        # move the cut hid is not in the position, so its σ must say so)
        pos, std = regs["POSITION"], regs["POSITION_STD"]
        assert max(abs(pos), abs(pos - STROKE_M)) <= 3 * std, (pos, std)

    asyncio.run(with_gateway(tmp_path, args, body))


def test_a_cut_shorter_than_an_outage_is_bridged_and_stays_valid(tmp_path):
    """The line is cut for 0.4 × OUTAGE_S while the axis stands: the estimator bridges the
    gap (no start-over), the loss is counted, the estimate stays VALID and trusted. (A gap
    that short mid-stroke is bridged too, but the acceleration the board measured then is
    lost, and the velocity with it: untrusted until a stop is seen, as after an outage.)"""
    cut_s = 0.4 * OUTAGE_S
    args = ["--strokes", "2", "--cut-after", f"{REST_S / 2:g}", "--cut-for", f"{cut_s:g}"]

    async def body(gw, client):
        await valid_before_the_cut(gw)
        await wait_for(lambda: gw.fresh_values().lost_samples > 0, 30, what="the cut's samples lost")
        regs = await read_inputs(client)
        assert StatusBits.SAMPLES_LOST in StatusBits(regs["STATUS"])
        assert regs["LOST_SAMPLES"] == pytest.approx(lost_in(cut_s), abs=2)
        assert gw.intake.events.outage_at_s is None  # bridged: no start-over
        # VALID and trusted (polled: a host that lagged shows STALE meanwhile). Had the gap
        # cost the velocity, this could not pass: no quiet stretch of this scenario outlasts
        # QUIET_STOP_S (rests of 4 + 1 s, dwells of 1 s), so untrusted would stay
        await wait_for(lambda: StatusBits.VALID in status(gw) and StatusBits.POSITION_UNTRUSTED not in status(gw), 30,
                       what="VALID and trusted after a bridged gap")
        assert gw.intake.events.outage_at_s is None

    asyncio.run(with_gateway(tmp_path, args, body))
