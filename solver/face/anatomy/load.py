"""One entry point for every anatomy: 'generic' (procedural) or an ANSYS face folder."""

from pathlib import Path

from solver.core.errors import FaceFMUError, ParameterError
from solver.face.anatomy.half import half_anatomy

LEVELS = ("coarse", "medium", "paper", "fine")


def load_anatomy(spec="generic", level="coarse", half=False, rows=None):
    """spec: 'generic' or a folder path; level: one of LEVELS and rows: brick rows per
    layer (None: the level's), generic face only; half: keep x <= 0 with the mid-sagittal
    nodes on the symmetry plane."""
    if str(spec) == "generic":
        if level not in LEVELS:
            raise ParameterError(f"level {level!r} is not one of {list(LEVELS)}")
        from solver.face.anatomy.generic import generic_face
        return generic_face(level=level, half=half, rows=rows)
    if rows is not None:
        raise ParameterError("rows sets the generic face's mesh; an ANSYS face keeps its own")
    folder = Path(spec)
    if not folder.is_dir():
        raise FaceFMUError(f"anatomy folder {folder} does not exist (or use 'generic')")
    from solver.face.anatomy.ansys import load_ansys_face
    anatomy = load_ansys_face(folder)
    return half_anatomy(anatomy) if half else anatomy
