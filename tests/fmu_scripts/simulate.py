"""simulate_fmu with input signals, in a fresh process: python simulate.py FMU OUT.json"""

import json
import sys

import numpy as np
from fmpy import simulate_fmu

fmu_path, out_path = sys.argv[1], sys.argv[2]
signals = np.array([(0.0, 0.0, 0.0), (0.05, 1.0, 0.0), (0.1, 0.0, 1.0)],
                   dtype=[("time", float), ("OOP", float), ("RIS", float)])
res = simulate_fmu(fmu_path, stop_time=0.1, output_interval=0.01, input=signals,
                   output=["lip_aperture", "lip_protrusion", "lip_width", "newton_iterations",
                           "substeps"])
json.dump({name: res[name].tolist() for name in res.dtype.names}, open(out_path, "w"))
print("ok")
