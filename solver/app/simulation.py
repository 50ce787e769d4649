"""A simulation: a scene's anatomy, terms and analysis behind one small runtime API.

    sim = Simulation("rounding_u")              # a built-in scene, a file path or a Scene
    sim.set_activations({"OOP": 0.6})
    stats = sim.step(sim.t + 0.01)              # transient: adaptive substeps to the time
    sim.outputs()                               # lip measures (mm) and solver statistics
    state = sim.get_state(); sim.set_state(state)

This is what the FMU and the command line drive; it holds no physics of its own.
A step that fails (after every cutback) leaves the simulation at its last good state
and returns stats with converged = False. Simulation is the full model at any fidelity;
the reduced-order one (fidelity "realtime") is solver.rom.simulation.ReducedSimulation,
and solver.entry.open_simulation opens whichever a fidelity asks for.
"""

from pathlib import Path

import numpy as np

from solver.face.activation import check_activation
from solver.face.anatomy.base import MUSCLE_NAMES
from solver.face.anatomy.load import load_anatomy
from solver.core.errors import ParameterError
from solver.app.extras import need
from solver.face.face_model import FaceModel
from solver.app.fidelity import REDUCED, apply_fidelity
from solver.core.materials import MooneyRivlin
from solver.face.muscles import MuscleProperties
from solver.app.scene import GRAVITY, Scene, load_scene
from solver.core._cache import mark_kernels_warm
from solver.core.transient import StepStats, Transient
from solver.core.units import kg_per_m3

BUILTIN_DIR = Path(__file__).parent / "scenes"


def builtin_scenes():
    """Names of the built-in scenes."""
    return sorted(p.stem for p in BUILTIN_DIR.glob("*.toml"))


def resolve_scene(scene):
    """A Scene from a Scene, a built-in name or a TOML path."""
    if isinstance(scene, Scene):
        return scene
    path = BUILTIN_DIR / f"{scene}.toml"
    if path.is_file():
        return load_scene(path)
    return load_scene(scene)


def _contact_terms(anatomy, scene, jaw=None):
    from solver.face.terms.contact import build_contact_terms
    return build_contact_terms(anatomy, lips=scene.lip_contact, teeth=scene.teeth_contact,
                               lip_penalty=scene.lip_penalty, jaw=jaw)


class SceneDriver:
    """A scene's standalone run, for any simulation with scene, t, face, jaw,
    set_inputs, step and outputs (Simulation, and the reduced model of
    solver.rom.simulation, which holds a Simulation instead of being one)."""

    def set_activations(self, values):
        """Target activations for the next step: dict muscle -> a in [0, 1] (the others
        keep theirs); a bad value raises ParameterError naming it, nothing changed."""
        self.set_inputs(activations=values)

    def set_jaw(self, opening=None, protrusion=None):
        """Target jaw opening (deg, about the TMJ axis) and protrusion (mm, along the
        occlusal plane) for the next step (solver.face.jaw); None keeps one. Values outside
        solver.face.jaw.JAW_RANGES, or an anatomy without a jaw, raise ParameterError and
        change nothing."""
        if self.face.jaw is None:
            raise ParameterError(_no_jaw(self.anatomy))
        self.set_inputs(jaw=(opening, protrusion))

    def run(self, progress=False, on_record=None):
        """A standalone run of the scene's schedules: records (list of dicts) at every
        output interval up to the scene's duration. on_record(sim, row) is called at each."""
        sc = self.scene
        times = np.arange(1, int(round(sc.duration / sc.interval)) + 1) * sc.interval
        rows = [self._record()]
        if on_record:
            on_record(self, rows[0])
        iterator = times
        if progress:
            tqdm = need("tqdm", "sweep", "a progress bar (Simulation.run(progress=True))").tqdm
            iterator = tqdm(times, desc=sc.name, unit="record")
        for t in iterator:
            self.set_activations(sc.activations(t))
            jaw = sc.jaw(t)
            if jaw:
                self.set_jaw(jaw.get("jaw_opening"), jaw.get("jaw_protrusion"))
            stats = self.step(float(t))
            if not stats.converged:
                raise RuntimeError(f"scene {sc.name}: step to t = {t:.4g} s failed: "
                                   f"{stats.reason}")
            rows.append(self._record())
            if on_record:
                on_record(self, rows[-1])
        return rows

    def _record(self):
        out = self.outputs()
        row = {"time": self.t}
        row.update({k: v for k, v in out.items() if k in self.scene.record
                    or (k.startswith("strain_") and "muscle_strains" in self.scene.record)})
        row.update(self.face.activation.as_dict(self.face.activation.start))
        if self.scene.jaw(0.0):
            row["jaw_opening"], row["jaw_protrusion"] = self.jaw
            row["incisor_opening"] = out["incisor_opening"]
        return row


def _no_jaw(anatomy):
    return (f"anatomy {anatomy.name!r} has no jaw (no 'fixed_mandible' node set or teeth "
            "surfaces)")


class Simulation(SceneDriver):
    """The full model. scene: Scene, built-in name or TOML path; fidelity: a preset name
    of solver.app.fidelity (applied before the overrides; a reduced-order one such as
    "realtime" is refused: solver.entry.open_simulation opens it); overrides: Scene fields
    to replace; loaded_anatomy: an Anatomy already in memory (instead of loading the
    scene's). A scene file that names "realtime" gets the full model at the realtime
    knobs here."""

    def __init__(self, scene="default", loaded_anatomy=None, fidelity=None, **overrides):
        if fidelity in REDUCED:
            raise ParameterError(f"fidelity {fidelity!r} is a reduced-order model, which "
                                 "Simulation does not build: open it with "
                                 f"solver.open_simulation(scene, fidelity={fidelity!r})")
        scene = resolve_scene(scene)
        if fidelity is not None:
            scene = apply_fidelity(scene, fidelity)
        if str(overrides.get("anatomy", "generic")) != "generic" and "rows" not in overrides:
            overrides["rows"] = None        # the scene's rows (e.g. its preset's) set the
                                            # generic mesh; an ANSYS face keeps its own
        self.scene = scene.with_overrides(**overrides) if overrides else scene
        sc = self.scene
        self.anatomy = loaded_anatomy or load_anatomy(sc.anatomy, sc.level, sc.half, sc.rows)
        props = MuscleProperties(force_scale={m: sc.force_scale.get(m, 1.0)
                                              for m in MUSCLE_NAMES},
                                 stiffening_rule=sc.stiffening_rule, **sc.muscle_constants())
        self.face = FaceModel(self.anatomy, MooneyRivlin(), muscles=sc.driven,
                              stiffening=sc.stiffening, properties=props,
                              formulation=sc.formulation, linear_solver=sc.linear_solver)
        model = self.face.model
        model.newton_options.rtol = sc.newton_rtol
        model.newton_options.utol = sc.newton_utol
        density = kg_per_m3(sc.density)
        if GRAVITY[sc.gravity] is not None:
            from solver.core.terms.gravity import Gravity
            model.add_term(Gravity(self.anatomy.mesh, density, GRAVITY[sc.gravity],
                                   g=sc.g * 1e3))
        self.contact = []
        if sc.lip_contact or sc.teeth_contact:
            self.contact = _contact_terms(self.anatomy, sc, self.face.jaw)
            for term in self.contact:
                model.add_term(term)
        if GRAVITY[sc.gravity] is not None:          # start from the rest state under gravity
            res = self.face.solve_static()
            if not res.converged:
                raise RuntimeError(f"no equilibrium under gravity: {res.reason}")
        self.integrator = None
        if sc.analysis == "transient":
            self.integrator = Transient(model, density, sc.alpha, sc.beta, sc.inertia,
                                        sc.damping, sc.substep_tol, sc.max_substep,
                                        sc.min_substep, sc.hold, method=sc.integrator,
                                        rtol=sc.substep_rtol)
        self.t = 0.0
        self.last = StepStats()
        self._warm = False

    @property
    def term_names(self):
        """The model's terms, by name, in the order the solver walks them."""
        return self.face.term_names

    def set_inputs(self, activations=None, jaw=None, undriven="error"):
        """The next step's targets, all checked before any changes (the one place where
        inputs are validated): activations, dict muscle -> a in [0, 1]; jaw, (opening deg,
        protrusion mm) with None keeping one. A muscle the scene does not drive must stay
        at 0 (undriven "error"), or is checked and then left out ("ignore"). Raises
        ParameterError naming the input and its value; returns the undriven muscles with a
        nonzero value that were left out."""
        face, values, pose, idle = self.face, {}, None, []
        for m, v in dict(activations or {}).items():
            if m in MUSCLE_NAMES and m not in face.muscles and v != 0 and undriven == "error":
                raise ParameterError(f"muscle {m} is not driven in this model "
                                     f"(driven: {', '.join(face.muscles) or 'none'})")
            v = check_activation(m, v)
            if m in face.muscles:
                values[m] = v
            elif v != 0:
                idle.append(m)
        if jaw is not None:
            opening, protrusion = jaw
            if face.jaw is not None:
                pose = face.jaw.pose(opening, protrusion)
            elif opening or protrusion:
                raise ParameterError(_no_jaw(self.anatomy))
        face.set_activations(values)
        if pose is not None:
            face.set_jaw(pose)
        return idle

    @property
    def jaw(self):
        """(opening deg, protrusion mm) of the last converged state; (0, 0) without a jaw."""
        j = self.face.jaw
        return (0.0, 0.0) if j is None else (float(j.start[0]), float(j.start[1]))

    def step(self, t_end):
        """Advance to t_end (transient) or solve the equilibrium (static); StepStats."""
        if self.integrator is not None:
            self.integrator.t = self.t
            stats = self.integrator.advance(t_end)
            self.face.end_step(stats.converged)         # inputs committed or rolled back
        else:
            res = self.face.solve_static()
            rel = res.relaxation
            stats = StepStats(converged=res.converged,
                              substeps=len(res.steps) + (rel.substeps if rel else 0),
                              newton_iterations=res.iterations
                              + (rel.newton_iterations if rel else 0),
                              cutbacks=res.cutbacks, reason=res.reason)
        if stats.converged:
            self.t = float(t_end)
            if not self._warm:                  # the kernels a step needs are compiled
                mark_kernels_warm()
                self._warm = True
        self.last = stats
        return stats

    def outputs(self):
        """dict: the lip measures (mm, solver.face.face_model.FaceModel.lip_outputs), incisor_opening
        (mm), contact_force (N), the last step's solver statistics, and with the record
        'muscle_strains' each driven muscle's extreme principal strains."""
        out = self.face.lip_outputs()
        out["incisor_opening"] = self.face.incisor_opening()
        out["contact_force"] = float(sum(getattr(t, "total_force", 0.0) for t in self.contact))
        out["newton_iterations"] = self.last.newton_iterations
        out["substeps"] = self.last.substeps
        out["cutbacks"] = self.last.cutbacks
        if "muscle_strains" in self.scene.record:
            for m, (lo, hi) in self.face.region_strains().items():
                out[f"strain_min_{m}"], out[f"strain_max_{m}"] = lo, hi
        return out

    def release(self):
        """Free the linear solver's native memory (the simulation stays usable)."""
        release = getattr(self.face.model.linear_solver, "release", None)
        if release:
            release()

    @property
    def u(self):
        """(n, 3) the current displacements (mm)."""
        return self.face.u

    @property
    def v(self):
        """(n, 3) the current velocities (mm/s; zero in a static analysis)."""
        return self.integrator.v if self.integrator is not None else np.zeros_like(self.face.u)

    def get_state(self, fresh=True):
        """Everything needed to resume: copies of arrays, plain floats. fresh: a model with
        caches that steer its next step (the reduced model's) drops them, so that the next
        step equals one after set_state of this state (False: a plain read, for a caller
        that only looks; nothing here to drop)."""
        tr = self.integrator
        hist = tr.history if tr is not None else None
        none = np.zeros((0, 3))
        return {"t": self.t, "u": self.face.u.copy(), "v": self.v.copy(),
                "activation": self.face.activation.start.copy(),
                "jaw": np.array(self.jaw),
                "h": tr.h if tr is not None else 0.0,
                # the integrator's history (BDF2: the state one substep back; h_prev 0:
                # none) and its step controller's last error
                "u_prev": hist[0].copy() if hist else none,
                "v_prev": hist[1].copy() if hist else none,
                "h_prev": hist[2] if hist else 0.0,
                "err_prev": tr.err_prev if tr is not None else 1.0,
                "pattern": self.face.model.system().snapshot()}

    def set_state(self, state):
        """Resume from a get_state dict: time, displacements, velocities, activations,
        jaw pose, substep size, the integrator's history (without it: none, the next substep
        a backward Euler one) and the contact's sparsity pattern (without "pattern": one
        picked at u)."""
        self.t = float(state["t"])
        self.face.model.u = np.array(state["u"], dtype=float).reshape(-1, 3)
        self.face.restore_inputs(state["activation"], state.get("jaw", (0.0, 0.0)))
        self.face.model.system().restore(self.face.model.u.ravel(),   # contact candidates
                                         state.get("pattern"))
        if self.integrator is not None:
            self.integrator.v = np.array(state["v"], dtype=float).reshape(-1, 3)
            self.integrator.h = float(state["h"])
            self.integrator.t = self.t
            h_prev = float(state.get("h_prev", 0.0))
            self.integrator.history = None if h_prev <= 0.0 else (
                np.array(state["u_prev"], dtype=float).reshape(-1, 3),
                np.array(state["v_prev"], dtype=float).reshape(-1, 3), h_prev)
            self.integrator.err_prev = float(state.get("err_prev", 1.0))
