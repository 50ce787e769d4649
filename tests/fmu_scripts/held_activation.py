"""Hold activations through the FMU with default parameters and keep the solver's state,
in a fresh process: python held_activation.py FMU OUT.json MUSCLES SECONDS [SCENE]

MUSCLES is a comma-separated list held at 1 from t = 0. Every 50 ms the FMU's serialized
state is written to OUT.stateN.npz (np.savez bytes, 'sim.u' is the displacement), so that
the test process can measure penetrations outside the FMU."""

import json
import sys
from pathlib import Path

from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

fmu_path, out_path, muscles, seconds = sys.argv[1], sys.argv[2], sys.argv[3], float(sys.argv[4])
scene = sys.argv[5] if len(sys.argv) > 5 else None
md = read_model_description(fmu_path)
vr = {v.name: v.valueReference for v in md.modelVariables}
fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(fmu_path),
                modelIdentifier=md.coSimulation.modelIdentifier, instanceName="held")
fmu.instantiate(loggingOn=True)      # fmpy prints the FMU's log messages
fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode()
if scene:
    fmu.setString([vr["scene"]], [scene])
fmu.exitInitializationMode()
names = ["lip_aperture", "lip_protrusion", "lip_width", "contact_force"]
rows, states = [], []
fmu.setReal([vr[m] for m in muscles.split(",")], [1.0] * len(muscles.split(",")))
t, dt = 0.0, 0.01
for k in range(int(round(seconds / dt))):
    fmu.doStep(t, dt)
    t += dt
    rows.append(dict(zip(names, fmu.getReal([vr[n] for n in names])), time=t))
    if (k + 1) % 5 == 0:
        path = Path(f"{out_path}.state{len(states)}.npz")
        path.write_bytes(bytes(fmu.serializeFMUstate(fmu.getFMUstate())))
        states.append(str(path))
fmu.terminate()
fmu.freeInstance()
json.dump({"rows": rows, "states": states}, open(out_path, "w"))
print("ok")
