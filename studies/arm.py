"""Case study I: the single link robot arm, θ from level, torque limited to 1 N m."""

from .runner import LoopSpec, Study, input_disturbance, measurement_noise, parameter_monte_carlo, \
    series_of_steps, step

STUDY = Study(
    plant="arm",
    tracked_unit="rad",
    input_unit="N m",
    scenarios=(
        step(),                                 # I.8(c): 50 deg, sized so that the PD just saturates
        series_of_steps(),
        input_disturbance(),                    # I.17(e): 0.2 N m
        measurement_noise({"theta": 1e-3}),     # rad; the text gives no sensor: an encoder-scale 0.06 deg
        parameter_monte_carlo(0.05),            # I.11(a): m and ell known to 5 %
    ),
    # I.14(c): 10x better tracking and disturbance rejection below 0.007 rad/s,
    # 10x better noise attenuation above 200 rad/s, relative to the PD loop.
    loops=(LoopSpec("I.14", "input", low_frequency=0.007, high_frequency=200.0, factor=10.0),),
)
