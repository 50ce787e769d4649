"""Where the published reference face's files are found (they never ship with the project).

``reference_face_dir()`` is $FACEFMU_REFERENCE_FACE where set, else
``../shared/data/reference-face`` beside the checkout; ``reference_face()`` is that folder
where it holds the model (its ``newface.node``), else None, so that tests, benchmarks and
examples skip the reference-face cases cleanly where it is absent.
"""

import os
from pathlib import Path

CHECKOUT = Path(__file__).resolve().parents[3]


def reference_face_dir() -> Path:
    """The folder where the reference face's ANSYS files are looked for."""
    env = os.environ.get("FACEFMU_REFERENCE_FACE")
    return Path(env) if env else CHECKOUT.parent / "shared" / "data" / "reference-face"


def reference_face():
    """reference_face_dir() where it holds the model's newface.node, else None."""
    folder = reference_face_dir()
    return folder if (folder / "newface.node").is_file() else None
