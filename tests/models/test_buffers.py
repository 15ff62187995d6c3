"""Kept result buffers (`models.buffers`): memory is reused only once every array of it is gone, a live
result is never written over, results do not depend on whether memory was reused, and the kept bytes stay
within their bound."""

import casadi as ca
import numpy as np
import pytest

import models
from models import buffers


class StateFeedback(models.Block):
    """u = -K x + kr r, reading the full state (a test fixture)."""

    def __init__(self, K, kr):
        K = np.asarray(K, dtype=float)
        gains = {"K": K, "kr": kr}
        super().__init__(
            sample_period=0.01, n_state=0, n_measured=K.size, n_reference=1, n_input=1, gains=gains, measures="state"
        )

    def expr(self, xc, y, r, g):
        return xc, -ca.dot(g["K"], y) + g["kr"] * r[0]


@pytest.fixture
def kept(monkeypatch):
    """A free list of its own for the test, within 1 MiB."""
    monkeypatch.setattr(buffers, "_free", [])
    monkeypatch.setattr(buffers, "KEPT_BYTES", 2**20)


def test_memory_is_reused_only_after_its_last_view_is_gone(kept):
    a, b = buffers.empty([(100, 3), (7,)])
    assert a.flags.c_contiguous and a.flags.writeable and a.dtype == np.float64 and b.shape == (7,)
    assert a.ctypes.data % buffers.ALIGNMENT == 0 and b.ctypes.data % buffers.ALIGNMENT == 0
    assert not np.shares_memory(a, b)
    view = a[10:, 1]
    address = a.ctypes.data
    del a, b
    assert buffers.kept_bytes() == 0  # a view still holds it
    (other,) = buffers.empty([(100, 3)])
    assert not np.shares_memory(other, view)
    del view
    assert buffers.kept_bytes() > 0
    (again,) = buffers.empty([(100, 3)])
    assert again.ctypes.data == address and buffers.kept_bytes() == 0


def test_only_a_similar_size_reuses_a_buffer_and_the_kept_bytes_stay_bounded(kept):
    (a,) = buffers.empty([(1000,)])
    address = a.ctypes.data
    del a
    (small,) = buffers.empty([(100,)])  # a tenth: fresh memory, the 8 kB buffer stays kept
    assert small.ctypes.data != address and buffers.kept_bytes() >= 8000
    (big,) = buffers.empty([(200_000,)])  # 1.6 MB, above the bound: never kept
    del big
    assert buffers.kept_bytes() < 2**20
    parts = [buffers.empty([(40_000,)])[0] for _ in range(4)]  # 4 x 320 kB: the oldest go beyond 1 MiB
    del parts
    assert 0 < buffers.kept_bytes() <= 2**20


def test_a_monte_carlo_in_reused_memory_gives_the_same_numbers_and_leaves_live_results_alone(kept):
    arm = models.get("arm")
    block = StateFeedback([0.6, 0.05], 0.6)
    samples = models.sample_params(arm, 5, seed=3)
    first = models.monte_carlo(arm, block, 0.3, 1.0, samples)
    copies = {name: getattr(first, name).copy() for name in ("x", "u", "xc", "diverged_at")}
    address = first.x.ctypes.data
    other = models.monte_carlo(arm, block, 0.1, 1.0, samples[::-1])  # while `first` lives: its own memory
    assert not np.shares_memory(other.x, first.x)
    for name, values in copies.items():
        np.testing.assert_array_equal(getattr(first, name), values, err_msg=name)
    del first
    again = models.monte_carlo(arm, block, 0.3, 1.0, samples)
    assert again.x.ctypes.data == address  # written into the memory `first` left
    for name, values in copies.items():
        np.testing.assert_array_equal(getattr(again, name), values, err_msg=name)
