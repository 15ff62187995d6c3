"""Case study V: the ball on a beam, ball position z tracked, tip force limited to 15 N."""

from .runner import LoopSpec, Study, input_disturbance, measurement_noise, parameter_monte_carlo, \
    series_of_steps, step

STUDY = Study(
    plant="ballbeam",
    tracked_unit="m",
    input_unit="N",
    scenarios=(
        step(),                                            # 0.25 -> 0.40 m (models.case: stays on the beam)
        series_of_steps(),                                 # V.15(e): a series of step changes
        input_disturbance(),                               # the text gives none: 10 % of 15 N (models.case)
        measurement_noise({"z": 1e-3, "theta": 1e-3}),     # m, rad; the text gives no sensors
        parameter_monte_carlo(0.05),                       # V.12(c): m1, m2, ell known to 5 %
    ),
    # The ball must stay on the beam: 0 <= z <= ell.
    bounds=lambda params: {"z": (0.0, params["ell"])},
    # V.13: inner (angle) loop bandwidth 20 rad/s, outer (position) loop 2 rad/s.
    loops=(LoopSpec("V.13(a)", "inner", baseline=None, crossover=20.0),
           LoopSpec("V.13(c)", "outer", baseline=None, crossover=2.0)),
    cascade=("theta", "z"),                                # V.6: F -> theta (inner), theta -> z (outer)
)
