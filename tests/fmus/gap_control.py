"""GapControl: a test controller FMU whose variables are named unlike LipMotorControl's.

It opens or closes the mouth towards `gap_target` (mm) by proportional feedback on
`mouth_gap` (mm, the face's lip aperture): `depressor` (DLI's activation) opens, `sphincter`
(OOP's) closes, `mandible` (deg) commands the jaw. Connected to FaceFMU only through a
system description (tests/test_batch.py)."""

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real


class GapControl(Fmi2Slave):
    author = "FaceFMU tests"
    description = "proportional mouth-gap controller with its own variable names"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.mouth_gap, self.depressor, self.sphincter, self.mandible = 0.0, 0.0, 0.0, 0.0
        self.gap_target, self.gain = 3.0, 0.5
        cont = dict(variability=Fmi2Variability.continuous)
        self.register_variable(Real("mouth_gap", causality=Fmi2Causality.input, **cont))
        for name in ("depressor", "sphincter", "mandible"):
            self.register_variable(Real(name, causality=Fmi2Causality.output, **cont))
        fixed = dict(causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed)
        self.register_variable(Real("gap_target", **fixed))
        self.register_variable(Real("gain", **fixed))

    def do_step(self, current_time, step_size):
        u = self.gain * (self.gap_target - self.mouth_gap)
        self.depressor = min(max(u, 0.0), 1.0)
        self.sphincter = min(max(-u, 0.0), 1.0)
        self.mandible = 2.0 if u > 0 else 0.0
        return True
