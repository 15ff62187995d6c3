"""The frequency measures of a loop (margins, disk margin, closed-loop bandwidth) agree with python-control,
a second computation: `stability_margins` on sampled loops (our margins there are our own crossing
search), `disk_margins` on a dense grid, `bandwidth` on continuous loops; a sampled integrator loop's
bandwidth against its closed form."""

import math
import warnings

import control
import numpy as np
import pytest

from designs.analysis.robustness import disk_margin_from_alpha, frequency_measures

PLANT = control.tf([1], [1, 1, 0])
LOOPS = {
    "lead on 1/(s(s+1))": PLANT * control.tf([2, 1], [0.1, 1]),
    "type 1, third order": control.tf([4], [1, 2, 0]) * control.tf([1], [0.2, 1]),
    "type 0, second order": control.tf([3], [1, 1.5, 1]),
    "sampled type 1": control.c2d(control.tf([4], [1, 2, 0]) * control.tf([1], [0.2, 1]), 0.02),
    "sampled lead": control.c2d(PLANT * control.tf([2, 1], [0.1, 1]), 0.05),
    "sampled lead on a lag": control.c2d(control.tf([5], [1, 3, 2]) * control.tf([1, 1], [0.1, 1]), 0.01),
}
#: python-control's grid: a coarse one, then a fine one around its smallest disk margin.
COARSE = np.logspace(-3, 2.4, 1001)


def _python_control_disk_margins(L):
    """control.disk_margins' smallest (α, gain, phase) margins on COARSE (below the Nyquist frequency of a
    sampled loop), then on 4001 points between the neighbours of its smallest α."""
    grid = COARSE[COARSE < 0.999 * math.pi / L.dt] if L.isdtime(strict=True) else COARSE
    alpha = control.disk_margins(L, grid, returnall=True)[0]
    i = int(np.argmin(alpha))
    fine = np.linspace(grid[max(i - 1, 0)], grid[min(i + 1, grid.size - 1)], 4001)
    return control.disk_margins(L, fine)


@pytest.mark.parametrize("name", LOOPS)
def test_margins_and_disk_margin_agree_with_python_control(name):
    L = LOOPS[name]
    found = frequency_measures(L)
    assert found.stable
    with np.errstate(divide="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore")  # python-control's note that it falls back on its frequency-data method
        gm, pm, *_ = control.stability_margins(L)
    gm_db = 20 * np.log10(gm) if np.isfinite(gm) else math.inf
    assert found.gain_margin_db == pytest.approx(gm_db, rel=1e-6)
    assert found.phase_margin_deg == pytest.approx(pm, rel=1e-6)
    alpha, disk_gain, disk_phase = _python_control_disk_margins(L)
    assert found.disk_margin == pytest.approx(alpha, rel=1e-6)
    assert found.disk_margin <= alpha * (1 + 1e-12)  # ours is the refined peak: never above the grid's value
    assert found.disk_gain_margin_db == pytest.approx(disk_gain, rel=1e-6)
    assert found.disk_phase_margin_deg == pytest.approx(disk_phase, rel=1e-6)


@pytest.mark.parametrize("name", [n for n, L in LOOPS.items() if not L.isdtime(strict=True)])
def test_bandwidth_agrees_with_python_control(name):
    L = LOOPS[name]
    assert frequency_measures(L).bandwidth_rad_s == pytest.approx(control.bandwidth(control.feedback(L, 1)), rel=1e-6)


@pytest.mark.parametrize("k", [0.05, 0.3])
def test_sampled_integrator_bandwidth_is_its_closed_form(k):
    """L = k/(z − 1): T = k/(z − a), a = 1 − k, so |T(e^{jωTs})|² = k²/(1 − 2a cos ωTs + a²); T(1) = 1 and
    the −3 dB frequency solves k² = 10^(−0.3) (1 − 2a cos ωTs + a²)."""
    ts, a = 0.01, 1 - k
    expected = math.acos((1 + a**2 - k**2 * 10**0.3) / (2 * a)) / ts
    found = frequency_measures(control.tf([k], [1, -1], ts))
    assert found.bandwidth_rad_s == pytest.approx(expected, rel=1e-9)


def test_disk_margin_formulas():
    """α = 2 tan(φ/2) for the disk's phase margin φ, and (1 + α/2)/(1 − α/2) its gain margin."""
    for alpha in (0.1, 0.5, 1.0, 1.9):
        gain, phase = disk_margin_from_alpha(alpha)
        assert 2 * math.tan(math.radians(phase) / 2) == pytest.approx(alpha, rel=1e-12)
        assert 10 ** (gain / 20) == pytest.approx((1 + alpha / 2) / (1 - alpha / 2), rel=1e-12)


def test_an_unstable_closed_loop_has_no_disk_margin():
    L = control.tf([20], [1, 1, 1]) * control.tf([1], [0.5, 1])  # gain beyond the gain margin
    found = frequency_measures(L)
    assert not found.stable and found.disk_margin == 0.0 and math.isnan(found.bandwidth_rad_s)


def test_a_mimo_loop_or_a_positive_dbdrop_is_refused():
    with pytest.raises(ValueError, match="SISO"):
        frequency_measures(control.ss(np.eye(2) * -1, np.eye(2), np.eye(2), np.zeros((2, 2))))
    with pytest.raises(ValueError, match="dbdrop must be a negative number of dB, got 3"):
        frequency_measures(LOOPS["type 0, second order"], dbdrop=3)
