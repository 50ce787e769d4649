"""A step the solver cannot take is refused (fmi2Discard), the state kept, and the next
valid step works. python nonconvergence.py FMU OUT.json SCENE"""

import json
import sys

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

fmu_path, out_path, scene = sys.argv[1:4]
md = read_model_description(fmu_path)
vr = {v.name: v.valueReference for v in md.modelVariables}
fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(fmu_path),
                modelIdentifier=md.coSimulation.modelIdentifier, instanceName="x")
fmu.instantiate(loggingOn=True)
fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode()
fmu.setString([vr["scene"]], [scene])
fmu.exitInitializationMode()
out = {}
fmu.doStep(0.0, 0.005)                        # at rest: fine
before = fmu.getReal([vr["lip_protrusion"], vr["lip_width"]])
fmu.setReal([vr["OOP"]], [1.0])               # 300 N per fibre: tissue inverts
try:
    fmu.doStep(0.005, 0.005)
    out["status"] = 0
except FMICallException as exc:
    out["status"] = exc.status
out["unchanged"] = fmu.getReal([vr["lip_protrusion"], vr["lip_width"]]) == before
fmu.setReal([vr["OOP"]], [0.002])             # 0.6 N per fibre: fine
fmu.doStep(0.005, 0.005)                      # same start time: the FMU stayed at 0.005
out["after"] = fmu.getReal([vr["lip_protrusion"], vr["lip_width"]])
fmu.terminate()
fmu.freeInstance()
json.dump(out, open(out_path, "w"))
print("ok")
