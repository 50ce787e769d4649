"""FaceFMU: the FMI 2.0 co-simulation slave (pythonfmu). No physics here: it maps FMU
variables to the simulation that solver.entry.open_simulation opens (solver.app.simulation.
Simulation, or solver.rom.simulation.ReducedSimulation at fidelity "realtime").

What a master sees:
* doStep with a bad input (an activation that is NaN, inf or outside [0, 1]; a step size
  that is not > 0; a current time that is not the FMU's time) returns fmi2Discard, with an
  fmi2Discard log message naming the variable and the value; the state stays at the last
  good point, and the next valid doStep works.
* doStep whose solver cannot converge after every cutback: the same (fmi2Discard), logged
  with the solver's reason.
* A parameter that cannot be used (unknown scene or fidelity, missing anatomy folder, bad
  level) is logged as an error at exitInitializationMode, which then fails with fmi2Fatal
  (pythonfmu turns exceptions into fmi2Fatal); setting a parameter after initialization is
  logged as a warning and ignored.
* fidelity: "balanced" (default) and the other presets of solver.app.fidelity (fast,
  accurate) set the mesh level, half face, substep and Newton tolerances and the element
  formulation themselves: the parameters level, half_face, tolerance and max_substep are
  then not used, with a warning for each one the master set. "" runs the scene as its
  file states it, with those four parameters where the master set them.
* A parameter the master does not set leaves the scene file's own value (anatomy, level,
  half face, tolerances, fidelity); the start values in modelDescription.xml are those of
  the built-in scenes. "realtime" runs the scene's
  reduced-order model (solver.rom): the one packed in the FMU's resources/rom (python
  build_fmu.py --rom FILE or --with-realtime), else the user's cache; without a model for
  the scene, initialization logs the training command and ends in fmi2Fatal.
* The linear solver is the scene's (`auto`: MKL PARDISO in single precision with
  refinement where pypardiso is installed, else SuperLU), as in process.
Outputs change only in doStep (no direct feedthrough).
"""

import io
import math

import numpy as np
from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu.enums import Fmi2Status
from pythonfmu.default_experiment import DefaultExperiment

from solver.core.numba_config import configure_numba

configure_numba()              # before any kernel runs in this process (solver.core.numba_config)

from solver.face.anatomy.base import MUSCLE_FULL_NAMES, MUSCLE_NAMES  # noqa: E402
from solver.app.fidelity import FIDELITIES, REDUCED, fidelity_overrides
from solver.core.errors import ParameterError
from solver.face.jaw import JAW_INPUTS
from facefmu.model_description import extend_model_description

OUTPUT_DESCRIPTIONS = {
    "lip_aperture": "gap between upper and lower lip in the mid-sagittal plane (smallest "
                    "distance between the lip contours), 0 when they touch",
    "lip_protrusion": "forward (+y) displacement of the lips from rest: mean of the upper "
                      "and lower lip front points",
    "lip_width": "distance between the mouth corners",
    "upper_lip_protrusion": "forward displacement of the upper lip's front point from rest",
    "lower_lip_protrusion": "forward displacement of the lower lip's front point from rest",
    "contact_force": "total normal contact force, lip on lip and lips/cheeks on the teeth "
                     "(0 where the scene has no contact)",
    "incisor_opening": "distance the lower incisor point has moved from the upper one "
                       "(0 with the jaw closed)",
}
JAW_DESCRIPTIONS = {
    "jaw_opening": "jaw opening: rotation of the mandible about the TMJ axis (0 closed)",
    "jaw_protrusion": "jaw protrusion: translation of the mandible along the occlusal "
                      "plane, forward",
}
PARAMETERS = ("anatomy", "level", "scene", "half_face", "tolerance", "max_substep",
              "fidelity")
# parameters a fidelity preset decides, with their defaults
PRESET_PARAMETERS = {"level": "coarse", "half_face": True, "tolerance": 1e-3,
                     "max_substep": 5e-3}


class FaceFMU(Fmi2Slave):
    """The FMI 2.0 co-simulation slave: the inputs, outputs and parameters of the module
    docstring over the simulation of solver.entry.open_simulation."""

    author = "FaceFMU developers"
    description = ("Finite-element face (Nazari et al. orofacial model): ten muscle "
                   "activations in, lip aperture and protrusion out")
    version = "0.1.0"
    license = "BSD-3-Clause"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=0.3, step_size=0.005)

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        self.anatomy, self.scene, self.fidelity = "generic", "default", "balanced"
        for name, value in PRESET_PARAMETERS.items():
            setattr(self, name, value)
        for m in MUSCLE_NAMES:
            setattr(self, m, 0.0)
            self.register_variable(Real(m, causality=Fmi2Causality.input,
                                        variability=Fmi2Variability.continuous,
                                        description=f"activation of {MUSCLE_FULL_NAMES[m]}"))
        for name, text in JAW_DESCRIPTIONS.items():
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.input,
                                        variability=Fmi2Variability.continuous,
                                        description=text))
        for name, text in OUTPUT_DESCRIPTIONS.items():
            setattr(self, name, 0.0)
            self.register_variable(Real(name, causality=Fmi2Causality.output,
                                        variability=Fmi2Variability.continuous,
                                        description=text))
        self.newton_iterations, self.substeps, self.cutbacks = 0, 0, 0
        self.register_variable(Integer("newton_iterations", causality=Fmi2Causality.output,
                                       variability=Fmi2Variability.discrete,
                                       description="Newton iterations in the last doStep"))
        self.register_variable(Integer("substeps", causality=Fmi2Causality.output,
                                       variability=Fmi2Variability.discrete,
                                       description="accepted substeps in the last doStep"))
        self.register_variable(Integer("cutbacks", causality=Fmi2Causality.output,
                                       variability=Fmi2Variability.discrete,
                                       description="failed substeps retried with half the "
                                                   "step in the last doStep"))
        self.rom_fallbacks = 0
        self.register_variable(Integer("rom_fallbacks", causality=Fmi2Causality.output,
                                       variability=Fmi2Variability.discrete,
                                       description="fidelity realtime: the times the "
                                                   "reduced model handed over to the full "
                                                   "model so far (0 otherwise)"))
        self.rom_full_time = 0.0
        self.register_variable(Real("rom_full_time", causality=Fmi2Causality.output,
                                    variability=Fmi2Variability.discrete,
                                    description="fidelity realtime: simulated time the "
                                                "full model has run so far, after a "
                                                "handover (s; 0 otherwise)"))
        self._set = set()                       # the parameters the master has set

        def fixed(name):
            return dict(causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                        setter=lambda value: self._set_parameter(name, value))
        self.register_variable(String("anatomy", description="'generic' or the path of an "
                                      "ANSYS face folder", **fixed("anatomy")))
        self.register_variable(String("level", description="generic face resolution: coarse, "
                                      "medium, paper or fine", **fixed("level")))
        self.register_variable(String("scene", description="a built-in scene name or the "
                                      "path of a scene TOML file", **fixed("scene")))
        self.register_variable(Boolean("half_face", description="simulate x <= 0 with "
                                       "u_x = 0 on the mid-sagittal plane",
                                       **fixed("half_face")))
        self.register_variable(Real("tolerance", description="local error tolerance of a "
                                    "substep", **fixed("tolerance")))
        self.register_variable(Real("max_substep", description="largest substep",
                                    **fixed("max_substep")))
        self.register_variable(String("fidelity", description="a preset: "
                                      + ", ".join(FIDELITIES + tuple(REDUCED))
                                      + " (reduced-order; trained per scene), or '' (the "
                                      "scene with level, half_face, tolerance, "
                                      "max_substep); where it is not set, a scene file "
                                      "that names a fidelity keeps its own",
                                      **fixed("fidelity")))
        self.sim = None
        self.time = 0.0
        self._used = None

    def _set_parameter(self, name, value):
        setattr(self, name, value)
        self._set.add(name)

    def to_xml(self, model_options=dict()):
        return extend_model_description(super().to_xml(model_options))

    # -- life cycle ----------------------------------------------------------------------
    def setup_experiment(self, start_time, stop_time, tolerance):
        self.time = float(start_time or 0.0)

    def exit_initialization_mode(self):
        from solver.core._cache import compile_notice, kernels_warm
        from solver.entry import open_simulation
        if not kernels_warm():
            self.log(compile_notice(), Fmi2Status.ok)
            from solver.app.warm import warm_in_subprocess      # on every core at once
            warm_in_subprocess(log=lambda line: self.log(line, Fmi2Status.ok))
        try:
            overrides = self._overrides()
            self._used = {p: getattr(self, p) for p in PARAMETERS}
            self.sim = open_simulation(self.scene, fidelity=self.fidelity or None,
                                       **overrides)
        except Exception as exc:
            self.log(f"cannot build the model: {exc}", Fmi2Status.error)
            raise
        for warning in self.sim.scene.contact_warnings():
            self.log(warning, Fmi2Status.warning)
        self.sim.t = self.time
        self._publish()

    def terminate(self):
        if self.sim is not None:
            # the linear solver's native memory and MKL's pooled buffers, now rather
            # than at the importer's exit
            self.sim.release()

    def _overrides(self):
        """open_simulation's keyword overrides: the parameters the master has set (a scene
        file's own values stand where it has not), and the fidelity's."""
        from solver.entry import is_reduced
        from solver.app.simulation import resolve_scene
        scene = resolve_scene(self.scene)
        if scene.fidelity and "fidelity" not in self._set:
            self.fidelity = scene.fidelity          # the scene file's own choice
        out = {"anatomy": str(self.anatomy)} if "anatomy" in self._set else {}
        if not self.fidelity:
            for name, key, kind in (("level", "level", str), ("half_face", "half", bool),
                                    ("tolerance", "substep_tol", float),
                                    ("max_substep", "max_substep", float)):
                if name in self._set:
                    out[key] = kind(getattr(self, name))
        else:
            fidelity_overrides(self.fidelity)      # ParameterError naming it and the allowed
            for name in PRESET_PARAMETERS:
                if name in self._set:
                    self.log(f"parameter {name} = {getattr(self, name)!r} not used: fidelity "
                             f"{self.fidelity!r} sets it", Fmi2Status.warning)
        if is_reduced(scene, self.fidelity or None):
            out["rom_dirs"] = self._rom_dirs()
        return out

    def _rom_dirs(self):
        """Where reduced models are looked for first: the FMU's resources/rom."""
        from pathlib import Path
        if self.resources:
            folder = Path(self.resources) / "rom"
            if folder.is_dir():
                return [folder]
        return []

    # -- stepping ------------------------------------------------------------------------
    def _refuse(self, message):
        self.log(message, Fmi2Status.discard)
        return False

    def _check_inputs(self, current_time, step_size):
        if not (isinstance(step_size, (int, float)) and math.isfinite(step_size)
                and step_size > 0):
            return f"communication step size {step_size!r} must be > 0"
        if abs(current_time - self.time) > 1e-9 * max(1.0, abs(self.time)):
            return (f"doStep starts at t = {current_time!r} s but the FMU is at "
                    f"t = {self.time!r} s")
        return None

    def do_step(self, current_time, step_size):
        problem = self._check_inputs(current_time, step_size)
        if problem:
            return self._refuse(f"step refused: {problem}; the state stays at t = {self.time} s")
        for p in PARAMETERS:
            if getattr(self, p) != self._used[p]:
                self.log(f"parameter {p} changed to {getattr(self, p)!r} after "
                         f"initialization: ignored (still {self._used[p]!r})", Fmi2Status.warning)
                setattr(self, p, self._used[p])
        try:                        # the inputs, checked by the simulation (its API)
            idle = self.sim.set_inputs({m: getattr(self, m) for m in MUSCLE_NAMES},
                                       (self.jaw_opening, self.jaw_protrusion),
                                       undriven="ignore")
        except ParameterError as exc:
            return self._refuse(f"step refused: {exc}; the state stays at "
                                f"t = {self.time} s")
        if idle:
            self.log(f"inputs {', '.join(idle)} drive muscles that the scene "
                     f"'{self.scene}' does not build: ignored", Fmi2Status.warning)
        stats = self.sim.step(self.time + step_size)
        if not stats.converged:
            return self._refuse(f"step from t = {self.time} s refused: the solver did not "
                                f"converge after {stats.cutbacks} cutbacks ({stats.reason}); "
                                f"the state stays at t = {self.time} s")
        self.time = self.sim.t
        self._publish()
        return True

    def _publish(self):
        out = self.sim.outputs()
        for name in OUTPUT_DESCRIPTIONS:
            setattr(self, name, out[name])
        self.newton_iterations = int(out["newton_iterations"])
        self.substeps = int(out["substeps"])
        self.cutbacks = int(out["cutbacks"])
        self.rom_fallbacks = int(out.get("rom_fallbacks", 0))
        self.rom_full_time = float(out.get("rom_full_time", 0.0))

    # -- state ---------------------------------------------------------------------------
    def _get_fmu_state(self):
        state = {name: getattr(self, name) for name in
                 list(MUSCLE_NAMES) + list(JAW_INPUTS) + list(OUTPUT_DESCRIPTIONS)
                 + ["newton_iterations", "substeps", "cutbacks", "rom_fallbacks",
                    "rom_full_time", "time"]}
        if self.sim is not None:
            state["sim"] = self.sim.get_state()
        return state

    def _set_fmu_state(self, state):
        for name, value in state.items():
            if name != "sim":
                setattr(self, name, value)
        if "sim" in state and self.sim is not None:
            self.sim.set_state(state["sim"])
            self.sim.last.newton_iterations = int(state["newton_iterations"])
            self.sim.last.substeps = int(state["substeps"])
            self.sim.last.cutbacks = int(state.get("cutbacks", 0))

    @staticmethod
    def _fmu_state_to_bytes(state):
        flat = {k: np.asarray(v) for k, v in state.items() if k != "sim"}
        flat.update({f"sim.{k}": np.asarray(v) for k, v in state.get("sim", {}).items()})
        buf = io.BytesIO()
        np.savez(buf, **flat)
        return buf.getvalue()

    @staticmethod
    def _fmu_state_from_bytes(data):
        with np.load(io.BytesIO(bytes(data)), allow_pickle=False) as z:
            state, sim = {}, {}
            for k in z.files:
                v = z[k]
                v = v.item() if v.ndim == 0 else v
                if k.startswith("sim."):
                    sim[k[4:]] = v
                else:
                    state[k] = v
        if sim:
            state["sim"] = sim
        return state
