"""The simulator's robot-like path as test cases (and the path of
benchmarks/accuracy/robot_like_sweep.py): moves of −0.634, +0.961, −0.327 m at 0.2 m/s
with a 0.5 s and a 0.1 s stop, optionally a 5 mg offset step in the first move's cruise,
scored per move as the benchmarks score."""
import math

import numpy as np

from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.evaluation import move_errors
from gateway.core.motion_profiles import PiecewiseConstantAcceleration, Segment, jerk_limited
from gateway.core.sensor_model import INTERNAL_FILTER_RESISTOR_OHM, SensorParams
from gateway.core.simulator import simulate
from gateway.core.units import STANDARD_GRAVITY_MPS2 as G

SPEED_MPS = 0.2
ACC_MPS2 = 1.0
MOVES_M = (-0.634, +0.961, -0.327)
STOPS_S = (0.5, 0.1)
REST_S = 3.0


def robot_path(jerk_mps3: float = 0.0) -> PiecewiseConstantAcceleration:
    """The path; jerk_mps3 > 0: driven jerk-limited (an S-curve, as a robot controller moves)."""
    ramp = SPEED_MPS / ACC_MPS2
    segments = [Segment(REST_S, 0.0)]
    for i, d in enumerate(MOVES_M):
        sign = math.copysign(1.0, d)
        cruise = (abs(d) - SPEED_MPS * ramp) / SPEED_MPS
        segments += [Segment(ramp, sign * ACC_MPS2), Segment(cruise, 0.0), Segment(ramp, -sign * ACC_MPS2)]
        segments.append(Segment(STOPS_S[i] if i < len(STOPS_S) else REST_S, 0.0))
    return jerk_limited(PiecewiseConstantAcceleration(segments), jerk_mps3)


def sensor_for(rate_hz: float, sample_noise_mps2: float) -> SensorParams:
    """The board at rate_hz (RSET), its filter at a fifth of the rate (CX), the density that
    gives sample_noise_mps2 per sample at rest."""
    base = SensorParams()
    rset = base.rset_ohm * (500.0 / rate_hz)
    bandwidth = rate_hz / 10.0
    cx = 1.0 / (2.0 * math.pi * INTERNAL_FILTER_RESISTOR_OHM * bandwidth)
    density = sample_noise_mps2 / G / math.sqrt(math.pi / 2.0 * bandwidth)
    return SensorParams(rset_ohm=rset, filter_capacitor_f=cx, noise_density_g_per_rthz=density)


def robot_case(seed: int, step_mg: float, rate_hz: float = 100.0, noise_mps2: float = 0.005,
               jerk_mps3: float = 0.0):
    sensor = sensor_for(rate_hz, noise_mps2)
    run = simulate(robot_path(jerk_mps3), sensor, seed=seed)
    t = sample_times_s(run.t2, run.tick_hz)
    z = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
    if step_mg:  # the offset steps in the first move's cruise
        cruise = np.flatnonzero((np.abs(run.ref_vel_mps) == SPEED_MPS) & (run.ref_pos_m > -0.634 + 0.3))
        z[cruise[0]:] += step_mg * 1e-3 * G
    # (an S-curve's profile is a sum of shifted copies: its rests are zero to rounding)
    resting = (np.abs(run.ref_vel_mps) < 1e-12) & (np.abs(run.ref_acc_mps2) < 1e-9)
    return t, z, run.ref_pos_m, resting, from_sensor_model(sensor)


def worst_move_and_inside(track, ref, resting):
    moves = move_errors(track.pos_m, ref, resting)
    ends = np.array([m.end for m in moves])
    inside = np.abs(track.pos_m[ends] - ref[ends]) <= 3 * track.pos_std_m[ends] + 1e-4
    return max(m.percent for m in moves), bool(inside.all())
