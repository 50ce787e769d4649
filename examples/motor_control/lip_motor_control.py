"""LipMotorControl: a small motor-control model as an FMI 2.0 co-simulation FMU.

It turns a sequence of speech lip targets into the ten face muscle activations:
feedforward commands per target, integral feedback on the face's lip aperture and
protrusion (FMU inputs), and first-order activation dynamics (time constant tau, 30 ms):
a(t + h) = u + (a(t) - u) exp(-h / tau), exact for a command u held over the step.

Targets (aperture, protrusion in mm) are sized to what this face can do with its lip
muscles alone (the jaw is fixed in the model): see examples/README.md.
"""

import math

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real, String

MUSCLES = ("LLSAN", "LAO", "ZYG", "RIS", "BUC", "DAO", "DLI", "MENT", "OOP", "OOM")

# phoneme: (start s, aperture mm, protrusion mm, feedforward activations)
SEQUENCE = (
    ("a", 0.00, 2.0, -0.6, {"LLSAN": 0.8, "DLI": 0.8}),
    ("u", 0.15, 0.6, 0.0, {"OOP": 0.5, "OOM": 0.2}),
    ("i", 0.35, 1.2, -1.0, {"RIS": 0.7, "ZYG": 0.6, "LLSAN": 0.4, "DLI": 0.4}),
    ("p", 0.55, 0.0, -1.5, {"OOM": 0.9, "OOP": 0.6, "MENT": 0.3}),
)
OPENERS = ("LLSAN", "DLI")          # aperture up
CLOSERS = ("OOM",)                  # aperture down
PROTRUDERS = ("OOP",)               # protrusion up


def target_at(t):
    """(name, aperture, protrusion, feedforward) of the target active at time t."""
    active = SEQUENCE[0]
    for item in SEQUENCE:
        if t >= item[1] - 1e-12:
            active = item
    name, _, aperture, protrusion, feedforward = active
    return name, aperture, protrusion, feedforward


class LipMotorControl(Fmi2Slave):
    author = "FaceFMU developers"
    description = "Speech lip targets to ten muscle activations, with feedback"
    default_experiment = None

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.lip_aperture, self.lip_protrusion = 0.0, 0.0
        for name in ("lip_aperture", "lip_protrusion"):
            self.register_variable(Real(name, causality=Fmi2Causality.input,
                                        variability=Fmi2Variability.continuous,
                                        description=f"face feedback: {name} (mm)"))
        for m in MUSCLES:
            setattr(self, m, 0.0)
            self.register_variable(Real(m, causality=Fmi2Causality.output,
                                        variability=Fmi2Variability.continuous,
                                        description=f"activation of {m}"))
        self.target_aperture, self.target_protrusion, self.phoneme = 0.0, 0.0, "a"
        self.register_variable(Real("target_aperture", causality=Fmi2Causality.output,
                                    variability=Fmi2Variability.discrete))
        self.register_variable(Real("target_protrusion", causality=Fmi2Causality.output,
                                    variability=Fmi2Variability.discrete))
        self.register_variable(String("phoneme", causality=Fmi2Causality.output,
                                      variability=Fmi2Variability.discrete))
        self.tau, self.gain = 0.03, 3.0
        self.register_variable(Real("tau", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.fixed,
                                    description="activation time constant (s)"))
        self.register_variable(Real("gain", causality=Fmi2Causality.parameter,
                                    variability=Fmi2Variability.fixed,
                                    description="integral feedback gain (1/(mm s))"))
        self._i_ap, self._i_pr = 0.0, 0.0
        self._update_target(0.0)

    def _update_target(self, t):
        name, ap, pr, _ = target_at(t)
        if name != self.phoneme:
            self._i_ap, self._i_pr = 0.0, 0.0          # fresh integrators per target
        self.phoneme, self.target_aperture, self.target_protrusion = name, ap, pr

    def do_step(self, current_time, step_size):
        name, ap, pr, feedforward = target_at(current_time)
        self._update_target(current_time)
        self._i_ap += self.gain * (ap - self.lip_aperture) * step_size
        self._i_pr += self.gain * (pr - self.lip_protrusion) * step_size
        command = {m: feedforward.get(m, 0.0) for m in MUSCLES}
        for m in OPENERS:
            command[m] += max(self._i_ap, 0.0)
        for m in CLOSERS:
            command[m] += max(-self._i_ap, 0.0)
        for m in PROTRUDERS:
            command[m] += max(self._i_pr, 0.0)
        decay = math.exp(-step_size / self.tau)
        for m in MUSCLES:
            u = min(max(command[m], 0.0), 1.0)
            setattr(self, m, u + (getattr(self, m) - u) * decay)
        self._update_target(current_time + step_size)
        return True
