"""Exceptions raised by the solver. Every message names its culprit."""


class FaceFMUError(Exception):
    """Base class of all errors raised by the solver."""


class MeshError(FaceFMUError, ValueError):
    """A mesh that cannot be used: inverted or zero-volume brick, bad ids, bad shapes."""


class MeshFileError(MeshError):
    """A mesh file that cannot be read; the message names the file and the line."""

    def __init__(self, path, line, message):
        self.path, self.line = str(path), line
        where = f"{path}:{line}" if line is not None else f"{path}"
        super().__init__(f"{where}: {message}")


class ParameterError(FaceFMUError, ValueError):
    """An impossible parameter (negative modulus, NaN activation, unknown name)."""
