"""Case study VI: the gantry crane with two slung loads, car position x tracked, force limited to 5 kN."""

from .runner import LoopSpec, Study, input_disturbance, measurement_noise, parameter_monte_carlo, \
    series_of_steps, step

STUDY = Study(
    plant="crane",
    tracked_unit="m",
    input_unit="N",
    scenarios=(
        step(),                                                          # VI.14(e): 10 m
        series_of_steps(),
        input_disturbance(),                                             # the text gives none: 10 % of 5 kN
        measurement_noise({"x": 1e-2, "theta1": 1e-3, "theta2": 1e-3}),  # m, rad; the text gives none
        parameter_monte_carlo(0.05),                                     # VI.11(a): all but g known to 5 %
    ),
    # VI.13: inner (load angle) loop bandwidth 3 rad/s with 25 deg phase margin; outer (car) loop 0.5 rad/s.
    loops=(LoopSpec("VI.13(a)", "inner", baseline=None, crossover=3.0, phase_margin=25.0),
           LoopSpec("VI.13(b)", "outer", baseline=None, crossover=0.5)),
    # VI.6: the single-load crane without friction (m2 = ell2 = b = 0): F -> theta -> x.
    cascade=("theta", "x"),
    cascade_model=("crane1", {"b": 0.0}),
)
