"""Case study II: the inverted pendulum on a cart, cart position z tracked, force limited to 5 N."""

from .runner import LoopSpec, Study, input_disturbance, measurement_noise, parameter_monte_carlo, \
    series_of_steps, step

STUDY = Study(
    plant="pendulum",
    tracked_unit="m",
    input_unit="N",
    scenarios=(
        step(),                                              # II.8(h): 2 m
        series_of_steps(),
        input_disturbance(),                                 # II.16(c): 0.5 N
        measurement_noise({"z": 1e-3, "theta": 1e-3}),       # m, rad; the text gives no sensors
        parameter_monte_carlo(0.05),                         # II.11(a): m1, m2, ell, b known to 5 %
    ),
    # II.14(c), outer loop: 10x better below 0.001 rad/s, 10x more noise attenuation above 20 rad/s.
    loops=(LoopSpec("II.14", "outer", low_frequency=0.001, high_frequency=20.0, factor=10.0),),
    cascade=("theta", "z"),                                  # II.6(b): F -> theta (inner), theta -> z (outer)
)
