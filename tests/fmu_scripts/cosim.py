"""A short two-FMU co-simulation, in a fresh process: python cosim.py FACE OUT.json CTRL"""

import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "examples"))
from cosim_speech import cosimulate  # noqa: E402

face, out, ctrl = sys.argv[1], sys.argv[2], sys.argv[3]
rows = cosimulate(face, ctrl, stop=0.03, step=0.005, progress=False)
json.dump(rows, open(out, "w"))
print("ok")
