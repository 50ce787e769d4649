"""Assembly, linear-solve and static-solve time against the number of DOF.

Shell-like structured blocks (n x n x 3 bricks, like the face's three tissue layers),
from about 1k to 60k DOF, and the reference face's own tangent (all muscles, OOP at 0.5),
where the reference face is present ($FACEFMU_REFERENCE_FACE or
../shared/data/reference-face). Prints a table; with --csv PATH also writes it.

    python benchmarks/solver_scaling.py [--sizes 10 20 40 70] [--csv out.csv] [--md FILE]

Times are the best of --repeat runs after a warm-up (numba compiled and cached); each
linear solver's factorization and a solve on it are timed apart.
"""

import argparse
import os
import time
from pathlib import Path

import numpy as np

import solver
from solver.core.linsolve import available, make_solver
from solver.core.meshgen import box
from table import markdown, report


def best_of(fn, repeat):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def linear_times(K, b, repeat):
    """{NAME_s, NAME_factor_s, NAME_solve_s} for each available solver: a factorization of
    K plus one solve with b on it, and each apart (a solve on a factorization is what an
    iteration of modified Newton pays)."""
    row = {}
    for name in available():
        lin = make_solver(name)
        factor = best_of(lambda: lin.factorize(K), repeat)
        solve = best_of(lambda: lin.solve(b), repeat)
        row.update({f"{name}_s": factor + solve, f"{name}_factor_s": factor,
                    f"{name}_solve_s": solve})
    return row


def case(n, repeat):
    mesh = box(n, n, 3, (2.0 * n, 2.0 * n, 6.0))
    model = solver.Model(mesh)
    model.fix(mesh.node_sets["zmin"])
    model.prescribe(mesh.node_sets["zmax"], displacement=(0.0, 0.0, -1.5))
    sysm = model.system()
    u = np.zeros(sysm.ndof)
    u[sysm.prescribed] = -1.5 * (np.arange(len(sysm.prescribed)) % 3 == 2)
    sysm.assemble(u)                                                   # warm-up
    row = {"bricks": mesh.n_bricks, "dof": sysm.ndof, "free_dof": len(sysm.free),
           "assembly_s": best_of(lambda: sysm.assemble(u), repeat),
           "residual_s": best_of(lambda: sysm.residual(u), repeat)}
    r, data = sysm.assemble(u)
    K = sysm.reduction.matrix(data)
    b = -r[sysm.free]
    row["nnz"] = K.nnz
    row.update(linear_times(K, b, repeat))
    for name in available():
        m = solver.Model(mesh, linear_solver=name)
        m.fix(mesh.node_sets["zmin"])
        m.prescribe(mesh.node_sets["zmax"], displacement=(0.0, 0.0, -1.5))
        t = time.perf_counter()
        res = m.solve_static()
        row[f"static_{name}_s"] = time.perf_counter() - t
        row["newton_iterations"] = res.iterations
    return row


def face_case(repeat):
    """Factorize + solve the reference face's tangent (all muscles, OOP at 0.5)."""
    from solver.face.anatomy.load import load_anatomy
    from solver.face.anatomy.reference import reference_face_dir
    folder = reference_face_dir()
    if not folder.is_dir():
        print(f"(no reference face at {folder}: face case skipped)")
        return None
    face = solver.FaceModel(load_anatomy(folder))
    face.set_activations({"OOP": 0.5})
    sysm = face.model.system()
    t = time.perf_counter()
    res = face.solve_static()
    static = time.perf_counter() - t
    u = face.u.ravel()
    row = {"bricks": face.anatomy.mesh.n_bricks, "dof": sysm.ndof,
           "free_dof": len(sysm.free), "assembly_s": best_of(lambda: sysm.assemble(u), repeat),
           "residual_s": best_of(lambda: sysm.residual(u), repeat)}
    r, data = sysm.assemble(u)
    K = sysm.reduction.matrix(data)
    row["nnz"] = K.nnz
    row.update(linear_times(K, -r[sysm.free], repeat))
    row[f"static_{available()[0]}_s"] = static
    row["newton_iterations"] = res.iterations
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[10, 20, 40, 70])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--csv")
    ap.add_argument("--md", help="also write the table as markdown there, with the command, "
                                 "commit, date and machine (docs/generated/solver_scaling.md)")
    ap.add_argument("--no-face", action="store_true", help="skip the reference-face case")
    args = ap.parse_args(argv)
    rows = []
    if not args.no_face:
        row = face_case(args.repeat)
        if row:
            rows.append({"case": "reference face", **row})
            print(rows[-1], flush=True)
    for n in args.sizes:
        rows.append({"case": f"box {n}x{n}x3", **case(n, args.repeat)})
        r = rows[-1]
        print("  ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}"
                        for k, v in r.items()), flush=True)
    print()
    report(rows, csv_path=args.csv, missing="")
    if args.md:
        write_md(args.md, rows, argv)


def write_md(path, rows, argv=None):
    """rows as a markdown table at path, after a line naming the command that made it."""
    from solver.app.provenance import command, stamp
    head = (f"`{command('benchmarks/solver_scaling.py', argv)}` {stamp()}, "
            f"{os.cpu_count()} cores:")
    Path(path).write_text("\n".join([head, ""] + markdown(rows, missing="")) + "\n")


if __name__ == "__main__":
    main()
