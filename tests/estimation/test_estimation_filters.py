"""The filters against independent computations: filterpy, Van Loan's matrix exponential,
a generic RTS smoother with pseudo-inverses, closed forms, and the compiled loop against
the same step run as plain Python."""
import numpy as np
import pytest
from filterpy.common import Q_continuous_white_noise
from filterpy.kalman import KalmanFilter
from scipy.linalg import expm

from gateway.core import estimator_kernel as K
from gateway.core.conversion import AxisCalibration, acceleration_mps2, sample_times_s
from gateway.core.estimator import RealtimeEstimator, estimate_series
from gateway.core.estimator_settings import from_sensor_model
from gateway.core.jit import JIT_ENABLED
from gateway.core.kalman_paper import (
    H_ACCELERATION,
    PaperKalmanFilter,
    process_noise,
    run_paper_filter,
    transition,
)
from gateway.core.motion_profiles import PiecewiseConstantAcceleration, Segment
from gateway.core.sensor_model import SensorParams
from gateway.core.simulator import simulate
from gateway.core.smoother import run_backward

# ---- the paper's filter ------------------------------------------------------------------

@pytest.mark.parametrize("dt", [1e-3, 2.01e-3, 0.1])
def test_paper_q_is_filterpys_continuous_white_noise(dt):
    np.testing.assert_allclose(process_noise(dt, 7.0), Q_continuous_white_noise(3, dt, spectral_density=7.0),
                               rtol=1e-14, atol=0)


def test_paper_filter_matches_filterpy_step_by_step():
    rng = np.random.default_rng(101)
    W, R = 1000.0, 4e-4
    ours = PaperKalmanFilter(W, R)
    ref = KalmanFilter(dim_x=3, dim_z=1)
    ref.x = np.zeros(3)
    ref.P = np.diag([0.0, 0.0, R])
    ref.H = H_ACCELERATION
    ref.R = np.array([[R]])
    for _ in range(500):
        dt = rng.uniform(1e-3, 3e-3)
        z = rng.normal(0.0, 3.0)
        ours.step(dt, z)
        ref.predict(F=transition(dt), Q=Q_continuous_white_noise(3, dt, W))
        ref.update(np.array([z]))
        np.testing.assert_allclose(ours.x, ref.x, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(ours.P, ref.P, rtol=1e-9, atol=1e-18)


def test_paper_filter_integrates_a_bias_like_raw_integration():
    """The paper's known limit: with H = [0 0 1] a constant bias b is followed, not removed,
    and the position grows as b·t²/2."""
    b, dt = 0.01, 2e-3
    t = np.arange(0, 20.0, dt)
    states, _ = run_paper_filter(t, np.full(t.size, b), np.ones(t.size, bool), 1000.0, 4e-4)
    assert states[-1, 0] / (0.5 * b * t[-1] ** 2) == pytest.approx(1.0, rel=0.01)


# ---- the gateway's filter against a generic filterpy run -------------------------------

def _van_loan(dt, qv, qb):
    """Φ and Q of ẋ = A x + w, A = [[0,1,0],[0,0,−1],[0,0,0]], w ~ diag(0, qv, qb) — by expm."""
    A = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [0.0, 0.0, 0.0]])
    Qc = np.diag([0.0, qv, qb])
    M = np.zeros((6, 6))
    M[:3, :3] = -A
    M[:3, 3:] = Qc
    M[3:, 3:] = A.T
    E = expm(M * dt)
    phi = E[3:, 3:].T
    return phi, phi @ E[:3, 3:]


def _recording(seed, bad=True, with_hint=False):
    """A gentle move (0.3 m/s²: found late, so the filter rolls back), a stop, a sharp
    stroke of the paper's kind, a stop; with an invalid sample in motion and at rest and a
    gap of 7 samples in motion. with_hint: also the machine's "at rest" on the true rests
    (NaN elsewhere): the soft hinted velocity updates before each stop is accepted."""
    sensor = SensorParams()
    profile = PiecewiseConstantAcceleration(
        [Segment(1.0, 0.0), Segment(0.5, 0.3), Segment(0.5, -0.3), Segment(0.6, 0.0)]
        + [Segment(0.1, 10.0), Segment(0.1, 0.0), Segment(0.1, -10.0), Segment(0.8, 0.0)]
    )
    run = simulate(profile, sensor, seed=seed)
    t = sample_times_s(run.t2, run.tick_hz)
    z = acceleration_mps2(run.t1x, run.t2, AxisCalibration())
    hint = np.where((run.ref_vel_mps == 0.0) & (run.ref_acc_mps2 == 0.0), 1.0, np.nan)
    ok = np.ones(t.size, bool)
    lost = np.zeros(t.size, np.int64)
    if bad:
        ok[np.searchsorted(t, 1.3)] = False
        ok[np.searchsorted(t, 2.4)] = False
        gap = np.searchsorted(t, 2.75)
        keep = np.ones(t.size, bool)
        keep[gap:gap + 7] = False
        t, z, ok, hint = t[keep], z[keep], ok[keep], hint[keep]
        lost = np.zeros(t.size, np.int64)
        lost[gap] = 7
    if with_hint:
        return sensor, t, z, ok, lost, hint
    return sensor, t, z, ok, lost


def _forward_with_records(settings, t, z, ok, lost, hint):
    prm = settings.kernel_params()
    n = t.size
    state = K.new_state(prm)
    cols = [np.empty(n) for _ in range(10)]
    flags = np.empty(n, np.int32)
    st_x, st_p = np.empty((n, 3)), np.empty((n, 6))
    st_trans, st_zaru = np.empty(n, np.int8), np.empty((n, 2))
    zi, zd = np.empty(n, np.int64), np.empty((n, 5))
    nz = K.run_forward(prm, t, np.where(ok, z, 0.0), ok, lost, hint, state, *cols, flags,
                       True, st_x, st_p, st_trans, st_zaru, zi, zd)
    return prm, st_x.copy(), st_p.copy(), st_trans, st_zaru, zi[:nz], zd[:nz], flags


def _unpack(p6):
    return np.array([[p6[0], p6[1], p6[2]], [p6[1], p6[3], p6[4]], [p6[2], p6[4], p6[5]]])


def _oracle(prm, t, z, ok, lost, st_trans, st_zaru, zupt_index, zupt_data, flags):
    """filterpy's KalmanFilter, driven by the kernel's decisions (transition, updates) only
    — and, for a soft hinted velocity update, its noise and target: the record's S less
    the prior's velocity variance (half the velocity's range over the hinted samples), and
    the record's innovation plus the prior's velocity."""
    kf = KalmanFilter(dim_x=3, dim_z=1)
    zupt = {int(i): row for i, row in zip(zupt_index, zupt_data, strict=False)}
    xs, ps, priors, prior_ps, phis = [], [], [], [], []
    u_prev, u_prev2, prev_invalid, have_u = 0.0, 0.0, False, False
    kf.x, kf.P = np.zeros(3), np.diag([0.0, 0.0, prm[K.P_BIAS0_VAR]])
    for k in range(t.size):
        tr = st_trans[k]
        phi = np.eye(3)
        if tr in (K.T_MOTION, K.T_STANDSTILL):
            dt = t[k] - t[k - 1]
            ddrift = K.drift_at(t[k], prm) - K.drift_at(t[k - 1], prm)
            if tr == K.T_MOTION:
                phi, Q = _van_loan(dt, prm[K.P_QV], prm[K.P_QB])
                missing = dt if prev_invalid else (dt * lost[k] / (lost[k] + 1.0) if lost[k] else 0.0)
                u_in, missing_var = u_prev, prm[K.P_MISSING_VAR]
                if missing > 0 and ok[k] and have_u:  # between the valid neighbours (kernel step 1)
                    half = 0.5 * (z[k] - u_prev)
                    u_in, missing_var = u_prev + half * missing / dt, half * half + prm[K.P_R]
                g = np.array([0.5 * missing**2, missing, 0.0])
                Q = Q + missing_var * np.outer(g, g)
                if missing == 0 and ok[k]:
                    # how the acceleration moved inside the held period: a step at a uniformly
                    # unknown instant, bounded by the range of the period's mean and its
                    # neighbours', ±range·dt²/8 taken as uniform (kernel_propagate)
                    spread = max(u_prev2, u_prev, z[k]) - min(u_prev2, u_prev, z[k])
                    Q[0, 0] += (spread * dt * dt / 8.0) ** 2 / 3.0
                B = np.array([[0.5 * dt * dt, 0.0], [dt, 0.0], [0.0, 1.0]])
            else:
                phi = np.diag([1.0, 0.0, 1.0])
                Q = np.diag([0.0, 0.0, prm[K.P_QB] * dt])
                B = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 1.0]])
                u_in = u_prev
            kf.predict(u=np.array([u_in, ddrift]), B=B, F=phi, Q=Q)
        elif tr == K.T_RESET:
            kf.x, kf.P = np.zeros(3), np.diag([0.0, 0.0, prm[K.P_BIAS0_VAR]])
        priors.append(kf.x.copy())
        prior_ps.append(kf.P.copy())
        phis.append(phi)
        if k in zupt:
            # zero true velocity; the state's v lags it by τ·(z − b) (the sensor's filter)
            lagged = -prm[K.P_LAG] * (z[k] - kf.x[2]) if ok[k] else 0.0
            r = zupt[k][1] - kf.P[1, 1] if flags[k] & K.F_HINT_SOFT else prm[K.P_R_ZUPT]
            # a soft hinted update's target is the velocity now against the hinted samples'
            # mean (standstill.mean_velocity_offset, tested on its own): taken from the
            # record's innovation, so that this checks the update's algebra
            target = zupt[k][0] + kf.x[1] if flags[k] & K.F_HINT_SOFT else lagged
            kf.update(np.array([target]), R=np.array([[r]]), H=np.array([[0.0, 1.0, 0.0]]))
        if st_zaru[k, 1] > 0:
            kf.update(np.array([z[k]]), R=np.array([[prm[K.P_R]]]), H=np.array([[0.0, 0.0, 1.0]]))
        xs.append(kf.x.copy())
        ps.append(kf.P.copy())
        if ok[k]:
            u_prev2 = u_prev if have_u and not prev_invalid else z[k]
            u_prev, prev_invalid, have_u = z[k], False, True
        else:
            prev_invalid = True
    return np.array(xs), np.array(ps), np.array(priors), np.array(prior_ps), np.array(phis)


@pytest.fixture(scope="module", params=["no hint", "rest hint"])
def filtered(request):
    sensor, t, z, ok, lost, hint = _recording(seed=103, with_hint=True)
    if request.param == "no hint":
        hint = np.full(t.size, np.nan)
    settings = from_sensor_model(sensor)
    prm, st_x, st_p, st_trans, st_zaru, zi, zd, flags = _forward_with_records(settings, t, z, ok, lost, hint)
    oracle = _oracle(prm, t, z, ok, lost, st_trans, st_zaru, zi, zd, flags)
    return dict(t=t, z=z, ok=ok, lost=lost, settings=settings, prm=prm, st_x=st_x, st_p=st_p,
                st_trans=st_trans, st_zaru=st_zaru, zi=zi, zd=zd, flags=flags, oracle=oracle,
                hinted=request.param == "rest hint")


def test_the_run_exercises_every_kind_of_step(filtered):
    kinds = set(np.unique(filtered["st_trans"]).tolist())
    assert kinds == {K.T_NONE, K.T_MOTION, K.T_STANDSTILL, K.T_RESET}
    soft = np.count_nonzero(filtered["flags"] & K.F_HINT_SOFT)
    assert soft > 0 if filtered["hinted"] else soft == 0  # soft hinted velocity updates (records too)
    assert filtered["zi"].size - soft >= 2  # stops entered with a ZUPT
    assert np.any(filtered["flags"] & K.F_INPUT_INVALID) and np.any(filtered["flags"] & K.F_GAP)
    assert np.any(filtered["flags"] & K.F_ROLLBACK)


def test_kernel_matches_filterpy_with_van_loan_discretisation(filtered):
    xs, ps, *_ = filtered["oracle"]
    np.testing.assert_allclose(filtered["st_x"], xs, rtol=1e-8, atol=1e-10)
    P = np.array([_unpack(p) for p in filtered["st_p"]])
    scale = np.maximum(np.abs(ps).max(axis=(1, 2)), 1e-30)[:, None, None]
    assert np.max(np.abs(P - ps) / scale) < 1e-8


def test_smoother_matches_a_generic_rts_with_pseudo_inverses(filtered):
    f = filtered
    xs, ps, priors, prior_ps, phis = f["oracle"]
    n = xs.shape[0]
    x_s, p_s = xs.copy(), ps.copy()
    for k in range(n - 2, -1, -1):
        if f["st_trans"][k + 1] == K.T_RESET or f["st_trans"][k + 1] == K.T_NONE:
            continue  # nothing flows back past a reset or a hold before initialisation
        C = ps[k] @ phis[k + 1].T @ np.linalg.pinv(prior_ps[k + 1], rcond=1e-13, hermitian=True)
        x_s[k] = xs[k] + C @ (x_s[k + 1] - priors[k + 1])
        p_s[k] = ps[k] + C @ (p_s[k + 1] - prior_ps[k + 1]) @ C.T
    st_x = f["st_x"].copy()
    pos_var, vel_var, bias_var = np.empty(n), np.empty(n), np.empty(n)
    run_backward(f["t"], f["st_trans"], st_x, f["st_p"].copy(), f["st_zaru"], f["prm"][K.P_R], f["zi"], f["zd"],
                 f["zi"].size, pos_var, vel_var, bias_var)
    np.testing.assert_allclose(st_x[:, 0], x_s[:, 0], atol=1e-8)  # metres
    np.testing.assert_allclose(st_x[:, 1], x_s[:, 1], atol=1e-8)
    np.testing.assert_allclose(st_x[:, 2], x_s[:, 2], atol=1e-8)
    np.testing.assert_allclose(np.sqrt(pos_var), np.sqrt(np.maximum(p_s[:, 0, 0], 0)), rtol=1e-5, atol=1e-9)
    # the smoother uses the future: in motion it must differ from the filter
    moving = f["st_trans"] == K.T_MOTION
    assert np.max(np.abs(st_x[moving, 0] - f["st_x"][moving, 0])) > 1e-6


def test_motion_step_closed_form_q_is_van_loans():
    for dt in (2e-3, 0.05, 1.0):
        x, P = np.zeros(3), np.zeros((3, 3))
        K.propagate_motion(x, P, dt, 0.0, 0.0, 2.5e-6, 3e-9, 0.0, 0.0)
        _, Q = _van_loan(dt, 2.5e-6, 3e-9)
        np.testing.assert_allclose(P, Q, rtol=1e-9, atol=1e-25)


def test_long_standstill_bias_is_the_sample_mean_and_its_variance_r_over_n():
    """Closed form: with no random walk and a vague prior, the ZARU chain is a running mean."""
    settings = from_sensor_model(SensorParams(), bias_random_walk_mps2_per_rts=0.0, drift_c1_mps2=0.0)
    rng = np.random.default_rng(104)
    n = 5000
    t = np.arange(n) * settings.sample_period_s
    z = 0.1 + rng.normal(0.0, 0.002, n)
    track = estimate_series(t, z, method="realtime", settings=settings)
    first = int(np.argmax(track.initialised))
    used = z[first:]
    r = settings.zaru_variance_mps2_sq
    prior = settings.bias_initial_std_mps2**2
    expected = (used.sum() / r) / (1.0 / prior + used.size / r)
    assert track.bias_mps2[-1] == pytest.approx(expected, rel=1e-9)
    est = RealtimeEstimator(settings)
    for tk, zk in zip(t, z, strict=False):
        est.step(tk, zk)
    assert est.covariance[2, 2] == pytest.approx(1.0 / (1.0 / prior + used.size / r), rel=1e-9)
    assert np.all(track.pos_m[first:] == 0.0) and np.all(track.vel_mps[first:] == 0.0)


# ---- the daemon's class against the offline function; compiled against plain Python -----

def test_realtime_class_reproduces_the_offline_track():
    sensor, t, z, ok, lost = _recording(seed=105)
    settings = from_sensor_model(sensor)
    track = estimate_series(t, z, ok, method="realtime", settings=settings, lost_before=lost)
    est = RealtimeEstimator(settings)
    got = [est.step(tk, zk if okk else None, int(lk)) for tk, zk, okk, lk in zip(t, z, ok, lost, strict=False)]
    np.testing.assert_array_equal([e.flags for e in got], track.flags)
    np.testing.assert_allclose([e.pos_m for e in got], track.pos_m, rtol=0, atol=1e-12)
    np.testing.assert_allclose([e.vel_mps for e in got], track.vel_mps, rtol=0, atol=1e-12)
    np.testing.assert_allclose([e.pos_std_m for e in got], track.pos_std_m, rtol=1e-12, atol=1e-15)


@pytest.mark.skipif(not JIT_ENABLED,
                    reason="numba not available (not installed, or ADXLGW_NO_JIT set): no compiled loop to compare")
def test_compiled_loop_equals_the_plain_python_step():
    sensor, t, z, ok, lost, hint = _recording(seed=106, with_hint=True)
    settings = from_sensor_model(sensor)
    compiled = estimate_series(t, z, ok, method="realtime", settings=settings, lost_before=lost,
                               standstill_hint=hint)
    assert np.any(compiled.flags & K.F_HINT_SOFT)
    prm = settings.kernel_params()
    state = K.new_state(prm)
    py_step = K.step.py_func
    pos = np.empty(t.size)
    for k in range(t.size):
        K.set_hint(state, hint[k])
        py_step(state, prm, t[k], z[k] if ok[k] else 0.0, bool(ok[k]), int(lost[k]))
        pos[k] = state.out[K.O_POS]
    np.testing.assert_allclose(pos, compiled.pos_m, rtol=0, atol=1e-12)


def test_the_velocity_now_against_the_hinted_samples_mean_is_what_their_acceleration_says():
    """standstill.mean_velocity_offset: the velocity at each sample's start is known from
    the acceleration before it, up to one constant; the soft hinted update takes the
    mean to be zero, so v_now = v_now − mean v. Checked against a direct sum on a ring
    that wraps, with an invalid slot."""
    from gateway.core.standstill import mean_velocity_offset

    rng = np.random.default_rng(11)
    size, count, oldest, bias, period = 9, 6, 6, 0.02, 0.0115
    ring_z, ring_ok = rng.normal(0.0, 0.3, size), np.ones(size)
    ring_ok[(oldest + 2) % size] = 0.0
    slots = [(oldest + i) % size for i in range(count)]
    acc = np.array([(ring_z[j] - bias) * period if ring_ok[j] else 0.0 for j in slots])
    v = np.concatenate([[0.0], np.cumsum(acc)])[:count]  # at each slot's start; the last is now
    offset, half_range = mean_velocity_offset(ring_z, ring_ok, oldest, count, bias, period)
    assert offset == pytest.approx(v[-1] - v.mean(), abs=1e-15)
    assert half_range == pytest.approx(0.5 * (v.max() - v.min()), abs=1e-15)
