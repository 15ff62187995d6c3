"""Case study III: the satellite with flexible panels, panel angle φ tracked, torque limited to 5 N m."""

from .runner import LoopSpec, Study, input_disturbance, measurement_noise, parameter_monte_carlo, \
    series_of_steps, step

STUDY = Study(
    plant="satellite",
    tracked_unit="rad",
    input_unit="N m",
    scenarios=(
        step(),                                                      # III.8(g): 30 deg
        series_of_steps(),
        input_disturbance(),                                         # III.16(c): 0.5 N m
        # rad: star tracker on theta, strain gauge on phi - theta; the text gives no noise figures.
        measurement_noise({"theta": 1e-3, "phi_minus_theta": 1e-3}),
        parameter_monte_carlo(0.05),                                 # Js, Jp, k, b known to 5 %
    ),
    # III.14(c), outer loop: 10x better below 0.003 rad/s, 10x more noise attenuation above 10 rad/s.
    loops=(LoopSpec("III.14", "outer", low_frequency=0.003, high_frequency=10.0, factor=10.0),),
    cascade=("theta", "phi"),                                        # III.6(b): tau -> theta -> phi
)
