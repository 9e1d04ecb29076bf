"""The simulator's robot-like path (benchmarks/robot_like_sweep.py) as test cases: moves of
−0.634, +0.961, −0.327 m at 0.2 m/s with a 0.5 s and a 0.1 s stop, optionally a 5 mg
offset step in the first move's cruise, scored per move as the benchmarks score."""
import numpy as np

from benchmarks.robot_like_sweep import (
    SPEED_MPS,
    AxisCalibration,
    G,
    acceleration_mps2,
    robot_path,
    sample_times_s,
    sensor_for,
)
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.evaluation import move_errors
from gateway.core.simulator import simulate


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
