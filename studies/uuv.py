"""Case study IV: UUV roll φ, thruster torque limited to 50 N m."""

from .runner import CONTROLLERS, LoopSpec, Study, input_disturbance, measurement_noise, parameter_monte_carlo, \
    series_of_steps, step

STUDY = Study(
    plant="uuv",
    # IV.11's root-locus lead-lag is the UUV's own homework, listed after the loopshaped design.
    controllers=CONTROLLERS[:4] + ("lead-lag (IV.11)",) + CONTROLLERS[4:],
    tracked_unit="rad",
    input_unit="N m",
    scenarios=(
        step(),                                 # IV.8(b): 30 deg
        series_of_steps(),
        input_disturbance(),                    # the text gives none: 10 % of the 50 N m limit (models.case)
        measurement_noise({"phi": 1e-3}),       # rad; the text gives no sensor
        parameter_monte_carlo(0.05),            # m, b, L known to 5 %
    ),
    # IV.13: crossover about 2 rad/s (rise time about 1 s), phase margin at least 60 deg.
    loops=(LoopSpec("IV.13", "input", baseline=None, crossover=2.0, phase_margin=60.0),),
    # IV.11: "assume that we have turbo charged our thrusters so that we can produce a peak torque of 250 N-m".
    input_limits={"lead-lag (IV.11)": 250.0},
)
