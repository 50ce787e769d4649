"""The `facefmu` command line.

    facefmu version
    facefmu anatomy SPEC [--level coarse|medium|paper|fine] [--half]
                         [--export FILE.vtu|FILE.xdmf] [--png FILE.png]
    facefmu run SCENE [--out DIR] [--fidelity fast|balanced|accurate|realtime]
                      [--anatomy SPEC] [--level L] [--full] [--vtu]
    facefmu cosim SYSTEM.xml [--targets FILE ...] [--stop S] [--set SIM.VAR=VALUE]
                             [--grid SIM.VAR=V1,V2] [--workers N] [--scheduler ADDRESS]

Errors in the user's input (missing folder, broken file, bad option, unwritable output)
and a missing optional dependency (solver.app.extras: the message names the extra) print one
line to stderr naming the culprit and exit with status 2. A subcommand is an
entry of COMMANDS: name -> (help, add_arguments(parser), run(args) -> exit status).
"""

import argparse
import sys

from solver.core.numba_config import configure_numba

configure_numba()              # before numba's import (solver.core.numba_config)

from solver.face.anatomy.base import MUSCLE_NAMES  # noqa: E402
from solver.face.anatomy.load import LEVELS, load_anatomy
from solver.core.errors import FaceFMUError
from solver.app.extras import MissingExtra
from solver.app.fidelity import FIDELITIES, REDUCED

from . import run_scene

EXIT_USAGE = 2


class _Parser(argparse.ArgumentParser):
    """argparse with one-line errors (status 2) instead of usage dumps."""

    def error(self, message):
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")


class UserError(Exception):
    """An input problem reported as one line on stderr, exit status 2."""


# ---------------------------------------------------------------------------- version

def _version_arguments(parser):
    """No arguments."""


def _version(args):
    import solver
    print(solver.__version__)
    return 0


# ---------------------------------------------------------------------------- anatomy

def _anatomy_arguments(parser):
    parser.add_argument("spec", metavar="SPEC", help="'generic' or an ANSYS face folder")
    parser.add_argument("--level", default="coarse", choices=LEVELS, metavar="LEVEL",
                        help=f"mesh level of the generic face: {', '.join(LEVELS)} "
                             "(default coarse)")
    parser.add_argument("--half", action="store_true", help="keep the x <= 0 half")
    parser.add_argument("--export", metavar="FILE", help="write FILE.vtu or FILE.xdmf "
                        "(and FILE_muscles.*) for ParaView")
    parser.add_argument("--png", metavar="FILE", help="write a picture of the face")


def _anatomy(args):
    anatomy = _load(args.spec, args.level, args.half)
    print(describe_anatomy(anatomy))
    if args.export:
        from solver.app.io import export_anatomy
        for path in export_anatomy(anatomy, args.export):
            print(f"wrote {path}")
    if args.png:
        from solver.app.plot import plot_anatomy
        print(f"wrote {plot_anatomy(anatomy, args.png)}")
    return 0


def _load(spec, level, half):
    """load_anatomy, a missing generic-face module reported as a UserError."""
    try:
        return load_anatomy(spec, level=level, half=half)
    except ModuleNotFoundError as e:
        if spec != "generic" or e.name != "solver.face.anatomy.generic":
            raise
        raise UserError("the generic face is not available in this installation "
                        "(solver.face.anatomy.generic is missing)") from None


def describe_anatomy(anatomy):
    """Text summary of an anatomy: counts, bounding box, muscle table, landmarks."""
    mesh = anatomy.mesh
    half = ", half face (x <= 0)" if anatomy.half else ""
    lines = [f"anatomy {anatomy.name}{half}",
             f"  nodes {mesh.n_nodes}   bricks {mesh.n_bricks}   wedges {int(mesh.is_wedge.sum())}",
             "  bounding box (mm)"]
    lo, hi = mesh.nodes.min(axis=0), mesh.nodes.max(axis=0)
    for axis, a, b in zip("xyz", lo, hi):
        lines.append(f"    {axis}  {a:8.2f} .. {b:8.2f}   extent {b - a:7.2f}")
    lines += ["", *_muscle_table(anatomy), "", *_landmark_table(anatomy)]
    return "\n".join(lines)


def _muscle_table(anatomy):
    """Lines of the per-muscle fibre and cable counts, per side and total."""
    sides = ["left", "right"] + (["mid"] if any(f.side == "mid" for f in anatomy.fibres) else [])
    head = "".join(f"{s:>7}" for s in sides) + f"{'total':>7}"
    width = len(head)
    out = [f"  {'muscle':<8}{'fibres':^{width}}  {'cable elements':^{width}}".rstrip(),
           f"  {'':<8}{head}  {head}"]
    rows = [(m, [f for f in anatomy.fibres if f.muscle == m]) for m in MUSCLE_NAMES]
    rows.append(("all", anatomy.fibres))
    for name, fibres in rows:
        n_fib = [sum(f.side == s for f in fibres) for s in sides] + [len(fibres)]
        n_cab = [sum(f.n_cables for f in fibres if f.side == s) for s in sides]
        n_cab.append(sum(f.n_cables for f in fibres))
        out.append(f"  {name:<8}" + "".join(f"{n:>7}" for n in n_fib) + "  "
                   + "".join(f"{n:>7}" for n in n_cab))
    return out


def _landmark_table(anatomy):
    """Lines of the landmarks: name, node index, source node id, x y z (mm)."""
    mesh = anatomy.mesh
    out = [f"  {'landmark':<17}{'node':>6}{'id':>8}{'x':>10}{'y':>10}{'z':>10}"]
    for name, i in anatomy.landmarks.items():
        x, y, z = mesh.nodes[i]
        out.append(f"  {name:<17}{i:>6}{mesh.node_ids[i]:>8}{x:>10.2f}{y:>10.2f}{z:>10.2f}")
    return out


# ------------------------------------------------------------------------------- run

def _run_arguments(parser):
    run_scene.add_arguments(parser)
    parser.add_argument("--fidelity", choices=FIDELITIES + tuple(REDUCED), metavar="NAME",
                        help=f"a fidelity preset ({', '.join(FIDELITIES)}) for the level, "
                             "half face and solver tolerances; --level and --full win "
                             "over it (default: the scene's own settings); 'realtime': "
                             "the scene's trained reduced-order model (docs/realtime.md)")


def _run(args):
    from solver.app.warm import warm_kernels
    warm_kernels(log=lambda line: print(f"facefmu run: {line}", file=sys.stderr))
    if args.fidelity:
        from solver.app.fidelity import apply_fidelity
        from solver.app.simulation import resolve_scene
        args.scene = apply_fidelity(resolve_scene(args.scene), args.fidelity)
        if args.fidelity in REDUCED:                 # the reduced model of that scene
            args.scene = args.scene.with_overrides(fidelity=args.fidelity)
    return run_scene.run(args)


# ----------------------------------------------------------------------------- cosim

def _cosim_arguments(parser):
    from . import cosim_cli
    cosim_cli.add_arguments(parser)


def _cosim(args):
    from . import cosim_cli
    try:
        return cosim_cli.run(args)
    except ValueError as exc:                   # a wrong description, file or option
        raise UserError(str(exc)) from None


COMMANDS = {
    "version": ("print the version", _version_arguments, _version),
    "anatomy": ("summarise a face anatomy; export it or draw it", _anatomy_arguments,
                _anatomy),
    "run": ("run a scene standalone: CSV, PNG and optional VTU frames",
            _run_arguments, _run),
    "cosim": ("co-simulate a system description: one utterance, or a batch on dask",
              _cosim_arguments, _cosim),
}


def build_parser():
    """The argparse parser with one subparser per entry of COMMANDS."""
    parser = _Parser(prog="facefmu", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND",
                                parser_class=_Parser)
    for name, (help_text, add_arguments, _) in COMMANDS.items():
        add_arguments(sub.add_parser(name, help=help_text, description=help_text))
    return parser


def main(argv=None):
    """Run the command line argv (default sys.argv[1:]); returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return COMMANDS[args.command][2](args)
    except (UserError, FaceFMUError, MissingExtra) as e:
        message = str(e)
    except OSError as e:
        message = f"{e.filename}: {e.strerror}" if e.filename else str(e)
    print(f"facefmu {args.command}: error: {message}", file=sys.stderr)
    return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
