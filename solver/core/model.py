"""The standalone static model: mesh, material, boundary conditions, load-stepped Newton.

    model = Model(mesh, MooneyRivlin())
    model.fix(ids); model.prescribe(ids, displacement=(0, 0, -4)); model.add_force(ids, f)
    res = model.solve_static()

Load stepping: every load (prescribed displacement, nodal force, and any term with a
load path) ramps from its value at the last converged solve to its new target with the
load factor lam in (0, 1]. A step that fails (divergence, det F <= 0 everywhere along
the line search, NaN, singular tangent) is cut back by half, at most ``max_cutbacks``
times in a row; a step that converges in few iterations lets the next one grow by 1.5.
A step cut below ``min_increment`` of the load fails the solve (a residual jump that no
smaller step crosses would otherwise creep on in ever smaller steps that succeed and fail
in turn). If the solve fails, the model keeps the state it had before the call.
"""

from dataclasses import dataclass, field

import numpy as np

from solver.core.errors import ParameterError
from solver.core.linsolve import make_solver
from solver.core.materials import MooneyRivlin
from solver.core.newton import NewtonOptions, newton
from solver.core.system import System
from solver.core.terms.elasticity import Elasticity
from solver.core.terms.loads import NodalForces


@dataclass
class StaticResult:
    """displacement (n, 3) mm; converged; iterations (Newton, total); steps: per load step
    dicts (lam, iterations, residuals); cutbacks; reason (why it failed, if it did)."""

    displacement: np.ndarray
    converged: bool
    iterations: int
    cutbacks: int
    steps: list = field(default_factory=list)
    reason: str = ""
    residual: np.ndarray = None

    def reaction(self, node_ids):
        """(3,) N: the support reaction summed over node_ids (force on the body)."""
        if self.residual is None:
            raise ValueError("no reaction: the solve did not converge")
        r = self.residual.reshape(-1, 3)
        return r[np.asarray(node_ids, dtype=np.int64)].sum(axis=0)


def _as_node_ids(mesh, node_ids):
    ids = np.atleast_1d(np.asarray(node_ids))
    if ids.size and not np.issubdtype(ids.dtype, np.integer):
        raise ParameterError(f"node ids must be integers, got {ids.dtype}")
    ids = ids.astype(np.int64).ravel()
    bad = ids[(ids < 0) | (ids >= mesh.n_nodes)]
    if len(bad):
        raise ParameterError(f"node id {bad[0]} is outside 0..{mesh.n_nodes - 1}")
    return ids


def _components(components):
    comps = np.asarray(components, dtype=np.int64).ravel()
    if np.any((comps < 0) | (comps > 2)):
        raise ParameterError(f"components {components} must be among 0, 1, 2")
    return comps


class Model:
    """A solid model: mesh, material (or per-brick params (m, 6)), terms and constraints."""

    def __init__(self, mesh, material=None, formulation="mean_dilatation",
                 linear_solver="auto"):
        material = MooneyRivlin() if material is None else material
        params = material.params if isinstance(material, MooneyRivlin) else material
        self.mesh = mesh
        self.u = np.zeros((mesh.n_nodes, 3))
        self._forces = None
        self.terms = [Elasticity(mesh, params, formulation)]
        self._target = {}                 # dof -> final prescribed value, mm
        self._system = None
        self.linear_solver = make_solver(linear_solver)
        self.newton_options = NewtonOptions()
        self.motions = []                 # prescribed motions along the load path

    # -- boundary conditions -------------------------------------------------------------
    def fix(self, node_ids, components=(0, 1, 2)):
        """Hold the given components of node_ids at zero displacement."""
        self.prescribe(node_ids, displacement=(0.0, 0.0, 0.0), components=components)

    def prescribe(self, node_ids, displacement, components=(0, 1, 2)):
        """Prescribe displacement (3,) or (k, 3) mm on the given components of node_ids."""
        ids = _as_node_ids(self.mesh, node_ids)
        comps = _components(components)
        disp = np.broadcast_to(np.asarray(displacement, dtype=np.float64), (len(ids), 3))
        if not np.all(np.isfinite(disp)):
            raise ParameterError("prescribed displacement has a non-finite value")
        dofs = (3 * ids[:, None] + comps[None, :]).ravel()
        keys = dofs.tolist()
        new = not self._target.keys() >= set(keys)
        self._target.update(zip(keys, disp[:, comps].ravel().tolist()))
        if new and self._system is not None:     # the set of prescribed DOFs changed
            self._reconstrain()

    def release(self, node_ids, components=(0, 1, 2)):
        """Remove prescriptions from node_ids."""
        for n in _as_node_ids(self.mesh, node_ids):
            for c in _components(components):
                self._target.pop(3 * int(n) + int(c), None)
        self._system = None if self._system is None else self._reconstrain()

    def add_motion(self, motion):
        """A prescribed motion along the load path: motion.dofs (k,) (prescribed DOFs),
        motion.dof_values(lam) (k,) mm and motion.moving (bool). Within a step its DOFs
        follow dof_values(lam) where the other prescribed DOFs ramp linearly (a rigid
        rotation stays rigid at every substep); at lam = 1 they must equal their targets."""
        self.motions.append(motion)

    def path_targets(self, pres, p_start, p_target, lam):
        """(p,) the prescribed DOFs pres (p,) at load factor lam: from p_start to p_target
        linearly, but for the moving motions' DOFs (add_motion)."""
        targets = p_start + lam * (p_target - p_start)
        for m in self.motions:
            if m.moving:
                targets[np.searchsorted(pres, m.dofs)] = m.dof_values(lam)
        return targets

    def add_force(self, node_ids, force):
        """Add a dead nodal force (3,) or (k, 3) N on node_ids (applied at the next solve)."""
        ids = _as_node_ids(self.mesh, node_ids)
        f = np.broadcast_to(np.asarray(force, dtype=np.float64), (len(ids), 3))
        if not np.all(np.isfinite(f)):
            raise ParameterError("nodal force has a non-finite value")
        dofs = (3 * ids[:, None] + np.arange(3)).ravel()
        self.forces.add(dofs, f.ravel())

    @property
    def forces(self):
        """The nodal-force term, created (and added to the terms) on first use."""
        if self._forces is None:
            self._forces = NodalForces(3 * self.mesh.n_nodes)
            self.add_term(self._forces)
        return self._forces

    def add_term(self, term):
        self.terms.append(term)
        self._system = None

    def remove_term(self, term):
        """Take a term out of the model (by identity); the system is rebuilt on next use."""
        self.terms = [t for t in self.terms if t is not term]
        self._system = None

    @property
    def elasticity(self):
        return self.terms[0]

    # -- solving -------------------------------------------------------------------------
    def _reconstrain(self):
        self._system.set_constraints(list(self._target))
        return self._system

    def system(self):
        if self._system is None:
            self._system = System(self.terms, self.mesh.n_nodes, list(self._target))
        return self._system

    def solve_static(self, steps=1, max_cutbacks=10, options=None, min_increment=1e-6,
                     max_steps=200):
        """Load-stepped Newton from the current state to the current targets; a
        StaticResult (converged False and a reason when the load could not be reached).

        The load increment halves after a failed step and grows by half after a step of
        at most 4 iterations. max_steps bounds the load steps tried: past a limit point,
        or where the contact's active set cycles, the steps shrink until each converges
        in a few iterations but no longer grow, and the load crawls (thousands of steps
        of 3e-4); such a solve is failed with the state restored, for a caller that can
        reach the equilibrium another way (solver.face.face_model.FaceModel.solve_static relaxes
        it)."""
        opts = options or self.newton_options
        sysm = self.system()
        self.linear_solver.invalidate()     # Newton's reuse starts afresh: solves repeat exactly
        pres = sysm.prescribed
        p_target = np.array([self._target[d] for d in pres])
        u_start = self.u.ravel().copy()
        pattern_start = sysm.snapshot()
        p_start = u_start[pres]
        u = u_start.copy()
        lam, dlam = 0.0, 1.0 / max(int(steps), 1)
        res = StaticResult(self.u.copy(), False, 0, 0)
        run_of_cuts = 0
        while lam < 1.0:
            if len(res.steps) >= max_steps:
                sysm.lam = 0.0
                sysm.restore(u_start, pattern_start)
                res.reason = (f"load stepping crawls: lam = {lam:.4g} after "
                              f"{len(res.steps)} load steps (at most {max_steps})")
                return res
            lam_try = min(1.0, lam + dlam)
            sysm.lam = lam_try
            targets = self.path_targets(pres, p_start, p_target, lam_try)
            u_new, r, rep = newton(sysm, u, targets, self.linear_solver, opts)
            res.iterations += rep.iterations
            res.steps.append({"lam": lam_try, "iterations": rep.iterations,
                              "residuals": rep.residuals, "converged": rep.converged,
                              "reason": rep.reason})
            if u_new is None:
                res.cutbacks += 1
                run_of_cuts += 1
                res.reason = rep.reason
                if run_of_cuts > max_cutbacks:
                    sysm.lam = 0.0
                    sysm.restore(u_start, pattern_start)
                    res.reason = (f"load step at lam = {lam_try:.4g} failed after "
                                  f"{max_cutbacks} cutbacks: {rep.reason}")
                    return res
                dlam *= 0.5
                if dlam < min_increment:
                    sysm.lam = 0.0
                    sysm.restore(u_start, pattern_start)
                    res.reason = (f"load step from lam = {lam:.6g} failed: the increment "
                                  f"fell below {min_increment:g} ({rep.reason})")
                    return res
                continue
            run_of_cuts = 0
            u, lam = u_new, lam_try
            sysm.commit(u)
            if rep.iterations <= 4:
                dlam *= 1.5
        self.u = u.reshape(-1, 3).copy()
        res.displacement = self.u.copy()
        res.converged, res.residual, res.reason = True, r, ""
        return res
