"""Clocks a user's recording may have: bursty, repeated and backward host times; arrival
times given as sample times; and one failing computation that must not lose the report."""
import json

import numpy as np
import pytest

import gateway.core.diagnosis.placement as placement
from gateway.cli import main
from gateway.core.diagnosis.timestamps import TimestampError, check_host_clock, check_sample_clock
from gateway.offline.recording import write_recording
from testing.diagnosis_cases import make_case, run_diagnosis


def _bursty_host(data, seed):
    """A host that reads the port every 16 ms and stamps each row near that instant,
    with 4 ms of scatter: 40–50 % of the steps go backwards, some are repeated."""
    rng = np.random.default_rng([seed, 99])
    burst = np.floor(data.t_s / 0.016) * 0.016 + 0.016
    host = np.round(burst + rng.normal(0.0, 0.004, len(data)), 4)  # 0.1 ms resolution: repeats
    data.t_host_s = host
    return host


@pytest.mark.parametrize("seed", [9100, 9101, 9102])
def test_backward_and_repeated_host_times_give_a_report_not_a_traceback(seed):
    _, data = make_case((), seed)
    host = _bursty_host(data, seed)
    steps = np.diff(host)
    assert np.mean(steps < 0) > 0.3 and np.any(steps == 0)
    result = run_diagnosis(data)
    doc = result.to_dict()
    json.dumps(doc)  # serialisable
    h = doc["timestamps"]["host"]
    assert h["backwards"] == int(np.sum(steps < 0)) and h["zero_intervals"] == int(np.sum(steps == 0))
    assert not h["strictly_increasing"]
    assert doc["failures"] == []
    timing = [e for e in result.effects if e.name == "timing"]
    if timing:  # its distance on host times cannot be made, and the report says why
        dist = timing[0].gain["distance"]
        assert not dist["available"] and "not increasing" in dist["why"]


def test_sample_clock_checks():
    t = np.arange(100) * 0.002
    assert check_sample_clock(t, np.zeros(100, int)) == pytest.approx(0.002)
    # a gap of 3 lost samples: the mean period counts them
    t_gap = np.concatenate([t[:50], t[50:] + 0.006])
    lost = np.zeros(100, int)
    lost[50] = 3
    assert check_sample_clock(t_gap, lost) == pytest.approx(0.002)
    bursty = np.repeat(np.arange(25) * 0.008, 4) + np.tile([0, 1e-4, 2e-4, 3e-4], 25)
    with pytest.raises(TimestampError, match="arrival times in bursts"):
        check_sample_clock(bursty, np.zeros(100, int))
    with pytest.raises(TimestampError, match="does not increase"):
        check_sample_clock(np.r_[t[:10], t[9], t[11:]], np.zeros(100, int))


def test_host_clock_counts_what_is_irregular():
    t = np.arange(200) * 0.002
    h = check_host_clock(t + 0.001, 0.002)
    assert h.strictly_increasing and h.why_no_estimate() is None and h.period_s == pytest.approx(0.002, rel=1e-3)
    back = t.copy()
    back[100] = back[98]
    h = check_host_clock(back, 0.002)
    assert h.backwards == 1 and "not increasing" in h.why_no_estimate() and h.why_not_retimed


def test_arrival_times_as_sample_times_exit_2_and_the_json_says_why(tmp_path):
    rng = np.random.default_rng(3)
    n = 2000
    true_t = np.arange(n) * 0.002
    arrival = np.floor(true_t / 0.016) * 0.016 + 0.016 + np.arange(n) % 8 * 1e-5  # bursts of 8, increasing
    acc = rng.normal(0.0, 0.02, n)
    path = tmp_path / "bursty.csv"
    write_recording(path, {"source": "import", "axis": "x"}, {"t_s": arrival, "acc_x_mps2": acc})
    out = tmp_path / "d.json"
    assert main(["diagnose", str(path), "--json", str(out)]) == 2
    doc = json.loads(out.read_text())
    assert doc["exit_code"] == 2 and "arrival times in bursts" in doc["error"]


def test_one_failing_gain_does_not_lose_the_report(monkeypatch):
    _, data = make_case(("scale_factor",), 9103)

    def broken(*args, **kwargs):
        raise ZeroDivisionError("float division by zero")

    monkeypatch.setattr(placement, "distance_gain", broken)
    result = run_diagnosis(data)
    assert [e.name for e in result.effects] == ["scale_factor"]  # judged without its distance
    dist = result.effects[0].gain["distance"]
    assert not dist["available"] and "ZeroDivisionError" in dist["why"]
    assert any("distance gain of scale_factor" in f["what"] for f in result.to_dict()["failures"])
    json.dumps(result.to_dict())

