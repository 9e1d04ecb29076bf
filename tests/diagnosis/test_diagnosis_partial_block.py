"""The record's last partial comparison block is compared, with its own weight.

A coarse reference makes blocks of b samples (context.Prepared.block); a record that is
not a whole number of blocks ends in a block of m < b samples — often the final rest,
where the distance is scored. It is compared as the mean of its own samples, whitened
and weighted by √(m/b) so that the likelihood's one variance holds for it too
(docs/diagnosis.md §4).
"""
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.signal import lfilter

from gateway.core.diagnosis.context import Prepared
from gateway.core.diagnosis.reading import WHITE

BLOCK = 10


def _prep(n: int) -> Prepared:
    ones = np.ones(n, bool)
    return Prepared(SimpleNamespace(), np.zeros(n), ones, np.zeros(n), ones.copy(), WHITE, block=BLOCK)


def test_the_last_partial_block_is_compared_as_the_mean_of_its_samples():
    n = 2 * BLOCK + 4
    prep = _prep(n)
    x = np.arange(n, dtype=float)
    mask = np.ones(n, bool)
    assert prep.compared_index(mask).tolist() == [0, BLOCK, 2 * BLOCK]
    assert prep.blocks(x, mask) == pytest.approx([4.5, 14.5, 21.5])
    white = prep.whiten_masked(x, mask)
    assert white[-1] == pytest.approx(21.5 * np.sqrt(4 / BLOCK))
    # a block with a sample outside the mask is not compared, the partial one included
    mask[-1] = False
    assert prep.compared_index(mask).tolist() == [0, BLOCK]
    assert prep.whiten_masked(x, mask).size == 2
    # a record of whole blocks: nothing changes
    assert _prep(2 * BLOCK).compared_index(np.ones(2 * BLOCK, bool)).tolist() == [0, BLOCK]


def _variance_ratio(noise: np.ndarray) -> float:
    """The variance of the partial block's whitened value over a full block's, over many records."""
    prep = _prep(noise.shape[1])
    mask = np.ones(noise.shape[1], bool)
    white = np.array([prep.whiten_masked(r, mask) for r in noise])
    return float(np.var(white[:, -1]) / np.var(white[:, :-1]))


def test_a_partial_block_weighs_as_a_full_one_in_white_noise_and_no_more_in_coloured():
    rng = np.random.default_rng(30)
    records, n = 4000, 3 * BLOCK + 3
    white = rng.normal(size=(records, n))
    # the sample variance ratio of 4000 values has a relative SE of ~3 %: ±15 % is 5 SE
    assert 0.85 < _variance_ratio(white) < 1.15
    # the sensor's low-pass colours its noise (lag-1 correlation 0.6): a mean of fewer
    # samples averages less away, so weighted by √(m/b) it is never counted above a full block
    coloured = lfilter([0.4], [1.0, -0.6], rng.normal(size=(records, n + 50)), axis=1)[:, 50:]
    assert _variance_ratio(coloured) < 1.0
