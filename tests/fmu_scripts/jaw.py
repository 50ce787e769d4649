"""The jaw through the FMU, in a fresh process: python jaw.py FMU OUT.json

Opens the jaw over three steps with OOP on, rolls a jaw step back and repeats it (from
getFMUstate and from its serialized bytes), and tries bad jaw inputs (each must be refused
with the state unchanged)."""

import json
import math
import sys

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

fmu_path, out_path = sys.argv[1], sys.argv[2]
md = read_model_description(fmu_path)
vr = {v.name: v.valueReference for v in md.modelVariables}

fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(fmu_path),
                modelIdentifier=md.coSimulation.modelIdentifier, instanceName="jaw")
fmu.instantiate(loggingOn=True, callbacks=None)
fmu.setupExperiment(startTime=0.0)
fmu.enterInitializationMode()
fmu.exitInitializationMode()
OUT = ["lip_aperture", "lip_protrusion", "incisor_opening", "contact_force"]


def outputs():
    return dict(zip(OUT, fmu.getReal([vr[n] for n in OUT])))


result = {"rest": outputs(), "opening": []}
t, dt = 0.0, 0.01
fmu.setReal([vr["OOP"]], [0.3])
for opening in (3.0, 6.0, 7.945):
    fmu.setReal([vr["jaw_opening"]], [opening])
    fmu.doStep(t, dt)
    t += dt
    result["opening"].append(outputs())
state = fmu.getFMUstate()
blob = fmu.serializeFMUstate(state)
runs = []
for restore in (None, lambda: fmu.setFMUstate(state),
                lambda: fmu.setFMUstate(fmu.deSerializeFMUstate(blob))):
    if restore:
        restore()
    fmu.setReal([vr["jaw_opening"], vr["jaw_protrusion"]], [4.0, 1.5])
    fmu.doStep(t, dt)
    runs.append(outputs())
result["rollback"] = runs
fmu.setFMUstate(state)
refused = []
for name, value in (("jaw_opening", math.nan), ("jaw_opening", 25.0), ("jaw_opening", -1.0),
                    ("jaw_protrusion", math.inf), ("jaw_protrusion", 11.0)):
    fmu.setReal([vr["jaw_opening"], vr["jaw_protrusion"]], [7.945, 0.0])
    fmu.setReal([vr[name]], [value])
    before = outputs()
    try:
        fmu.doStep(t, dt)
        refused.append([name, None])
    except FMICallException as exc:
        refused.append([name, exc.status])
    refused[-1].append(outputs() == before)
result["refused"] = refused
fmu.setReal([vr["jaw_opening"], vr["jaw_protrusion"]], [7.945, 0.0])
fmu.doStep(t, dt)
result["after_refusals"] = outputs()
fmu.terminate()
fmu.freeInstance()
json.dump(result, open(out_path, "w"))
print("ok")
