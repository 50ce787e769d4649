"""LipMotorControl: a speech motor-control model as an FMI 2.0 co-simulation FMU.

It turns a sequence of lip targets into the ten face muscle activations and the jaw
opening:

* Feedforward from an inverse model of the face. lipmc_inverse.LipMap f is the face's
  static map from four muscle synergies w (open, round, spread, close) to the lip
  aperture, protrusion and width, identified from FaceFMU's own responses (identify.py,
  stored in inverse_model.json, which this FMU carries). Each step the command is the
  map's bounded inverse of the desired outputs r*, its redundancy resolved towards the
  target's articulatory intent.
* Feedback on the face's outputs y (FMU inputs), by an internal model (an efference
  copy): a forward model predicts the outputs p from the activations actually sent,
      dp/dt = (f(w_a) - p) / tau_face,
  and the difference between the face and its prediction, filtered,
      dd/dt = (y - p - d) / tau_fb,
  is taken off the target: r* = r - d. At steady state d is the model's error there and
  the face reaches r. Anti-windup: the forward model runs on the activations after
  saturation (0..1) and activation dynamics, so d estimates model error only; it never
  integrates an error that the bounded muscles cannot remove (the command stays at its
  bound instead of winding up).
* Activation dynamics: first order, faster to activate than to relax (Zajac 1989;
  tau_act 15 ms, tau_deact 40 ms by default), exact for a command held over the step:
      a(t + h) = u + (a(t) - u) exp(-h / tau),  tau = tau_act if u > a else tau_deact,
  per synergy (its muscles share its activation) and hence per muscle.
* The jaw: each target names a jaw opening (deg; 0 where it does not), a feedforward
  command that the jaw follows with first-order dynamics of time constant tau_jaw
  (30 ms by default), exactly as above. The inverse and the forward model take the jaw
  opening actually sent (the output jaw_opening, the face's input of the same name).

Targets (mm) and their windows come from inverse_model.json (identify.py chose them from
what the identified map says the face reaches) or from a JSON file named by the
`targets_file` parameter: a list of {"phoneme", "duration" (s), "targeted" (a list of
output names), "lip_aperture", "lip_protrusion", "lip_width" (mm), optionally "intent"
({synergy: weight}) and "jaw_opening" (deg)}. After the last window the last target is
held.
"""

import json
import math
from pathlib import Path

import numpy as np

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Real, String
from pythonfmu.enums import Fmi2Status

from lipmc_inverse import MUSCLES, NAMES, OUTPUTS, LipMap, activations

TARGET_NAMES = {"lip_aperture": "target_aperture", "lip_protrusion": "target_protrusion",
                "lip_width": "target_width"}


def segment_at(targets, t):
    """Index of the target whose window holds time t (s); the last one after the end."""
    end = 0.0
    for k, tg in enumerate(targets):
        end += tg["duration"]
        if t < end - 1e-9:
            return k
    return len(targets) - 1


class LipMotorControl(Fmi2Slave):
    author = "FaceFMU developers"
    description = ("Speech lip targets to ten face muscle activations: inverse-model "
                   "feedforward, internal-model feedback, activation dynamics")
    default_experiment = None

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        cont = dict(variability=Fmi2Variability.continuous)
        for name in OUTPUTS:
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.input,
                                        description=f"face feedback: {name} (mm)", **cont))
        for m in MUSCLES:
            setattr(self, m, 0.0)
            self.register_variable(Real(m, causality=Fmi2Causality.output,
                                        description=f"activation of {m}", **cont))
        self.jaw_opening = 0.0
        self.register_variable(Real("jaw_opening", causality=Fmi2Causality.output,
                                    description="jaw opening command (deg)", **cont))
        disc = dict(causality=Fmi2Causality.output, variability=Fmi2Variability.discrete)
        for name in TARGET_NAMES.values():
            setattr(self, name, 0.0)
            self.register_variable(Real(name, description=f"{name} (mm)", **disc))
        self.phoneme = ""
        self.register_variable(String("phoneme", description="the current target", **disc))
        fixed = dict(causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed)
        self.tau_act, self.tau_deact, self.tau_fb, self.tau_face = 0.015, 0.04, 0.03, 0.0
        self.tau_jaw = 0.03
        for name, text in (("tau_act", "activation time constant (s)"),
                           ("tau_jaw", "the jaw's time constant (s)"),
                           ("tau_deact", "deactivation time constant (s)"),
                           ("tau_fb", "feedback filter time constant (s)"),
                           ("tau_face", "the forward model's time constant of the face "
                                        "(s; 0: the identified one)")):
            self.register_variable(Real(name, description=text, **fixed))
        self.targets_file = ""
        self.register_variable(String("targets_file", description="JSON list of targets "
                                      "('' : the ones in inverse_model.json)", **fixed))
        self._map, self._targets, self._k = None, None, -1
        self._w = None                           # commanded synergy weights (4,)
        self._a = np.zeros(len(NAMES))           # synergy activations, after dynamics
        self._p = self._d = None                 # prediction, filtered model error (3,)

    def exit_initialization_mode(self):
        self._map, data = LipMap.load(Path(self.resources) / "inverse_model.json")
        if self.tau_face <= 0.0:
            self.tau_face = float(data["tau_face"])
        self._targets = data["targets"]
        if self.targets_file:
            self._targets = json.loads(Path(self.targets_file).read_text())
        self._p = self._map(self._a)
        self._d = np.zeros(len(OUTPUTS))
        self._enter(0)

    def _enter(self, k):
        """Start target k: publish it and its output weights and intent."""
        tg = self._targets[k]
        self._k, self.phoneme = k, tg["phoneme"]
        for name, out in TARGET_NAMES.items():
            setattr(self, out, float(tg[name]))
        self._r = np.array([float(tg[name]) for name in OUTPUTS])
        self._q = np.array([1.0 if name in tg["targeted"] else 0.0 for name in OUTPUTS])
        intent = tg.get("intent", {})
        self._ref = np.array([float(intent.get(n, 0.0)) for n in NAMES])
        self._jaw = float(tg.get("jaw_opening", 0.0))

    def do_step(self, current_time, step_size):
        h = step_size
        k = segment_at(self._targets, current_time)
        if k != self._k:
            self._enter(k)
        y = np.array([getattr(self, name) for name in OUTPUTS], dtype=float)
        if not (np.all(np.isfinite(y)) and h > 0):
            bad = [f"input {n} = {v}" for n, v in zip(OUTPUTS, y) if not np.isfinite(v)]
            self.log(f"step refused: {', '.join(bad) or f'step size {h!r}'}; the state stays "
                     f"at t = {current_time} s", Fmi2Status.discard)
            return False
        self._d += (y - self._p - self._d) * (1.0 - math.exp(-h / self.tau_fb))
        self.jaw_opening = self._jaw + (self.jaw_opening - self._jaw) * math.exp(
            -h / self.tau_jaw)
        self._w = self._map.inverse(self._r - self._q * self._d, self._q, w0=self._w,
                                    w_ref=self._ref, jaw=self.jaw_opening)
        for i, u in enumerate(self._w):
            tau = self.tau_act if u > self._a[i] else self.tau_deact
            self._a[i] = u + (self._a[i] - u) * math.exp(-h / tau)
        for m, a in activations(self._a).items():
            setattr(self, m, a)
        f = self._map(self._a, self.jaw_opening)
        self._p = f + (self._p - f) * math.exp(-h / self.tau_face)
        k = segment_at(self._targets, current_time + h)
        if k != self._k:            # publish the target of the window that starts now
            self._enter(k)
        return True
