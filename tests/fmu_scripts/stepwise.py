"""Step-by-step FMU2Slave checks, run in a fresh process: python stepwise.py FMU OUT.json"""

import json
import math
import sys

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

fmu_path, out_path = sys.argv[1], sys.argv[2]
md = read_model_description(fmu_path)
vr = {v.name: v.valueReference for v in md.modelVariables}
unzip = extract(fmu_path)
messages = []


def logger(component, instance, status, category, message):
    messages.append((status, message.decode()))


def make(name):
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzip,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    fmu.instantiate(loggingOn=True, callbacks=None)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    return fmu


OUT = ["lip_aperture", "lip_protrusion", "lip_width", "upper_lip_protrusion",
       "lower_lip_protrusion"]


def outputs(fmu):
    vals = fmu.getReal([vr[n] for n in OUT])
    ints = fmu.getInteger([vr["newton_iterations"], vr["substeps"]])
    return dict(zip(OUT, vals)) | {"newton_iterations": ints[0], "substeps": ints[1]}


result = {}
fmu = make("a")
# a rest step, then OOP and RIS on
t, dt = 0.0, 0.01
fmu.setReal([vr["OOP"], vr["RIS"]], [0.8, 0.4])
for k in range(3):
    fmu.doStep(t, dt)
    t += dt
result["after_3"] = outputs(fmu)
# rollback: state at t, two steps, back, the same two steps
state = fmu.getFMUstate()
blob = fmu.serializeFMUstate(state)
fmu.doStep(t, dt)
fmu.doStep(t + dt, dt)
first = outputs(fmu)
fmu.setFMUstate(state)
fmu.doStep(t, dt)
fmu.doStep(t + dt, dt)
second = outputs(fmu)
fmu.setFMUstate(fmu.deSerializeFMUstate(blob))
fmu.doStep(t, dt)
fmu.doStep(t + dt, dt)
third = outputs(fmu)
result["rollback"] = [first, second, third]
fmu.setFMUstate(state)
# bad inputs: each refused with fmi2Discard, state unchanged, then a good step works
refused = []
for label, action in [("nan", lambda: fmu.setReal([vr["OOP"]], [math.nan])),
                      ("range", lambda: fmu.setReal([vr["OOP"]], [1.5])),
                      ("inf", lambda: fmu.setReal([vr["RIS"]], [math.inf]))]:
    action()
    before = outputs(fmu)
    try:
        fmu.doStep(t, dt)
        refused.append((label, None))
    except FMICallException as exc:
        refused.append((label, exc.status))
    assert outputs(fmu) == before
    fmu.setReal([vr["OOP"], vr["RIS"]], [0.8, 0.4])
for label, (start, step) in [("negative_step", (t, -dt)), ("zero_step", (t, 0.0)),
                             ("wrong_start", (t + 0.5, dt))]:
    try:
        fmu.doStep(start, step)
        refused.append((label, None))
    except FMICallException as exc:
        refused.append((label, exc.status))
result["refused"] = refused
fmu.doStep(t, dt)
result["after_refusals"] = outputs(fmu)
result["messages"] = messages
# a second instance in the same process, stepped alongside
other = make("b")
other.setReal([vr["OOP"]], [0.8])
other.doStep(0.0, dt)
fmu.doStep(t + dt, dt)
result["second_instance"] = outputs(other)
for f in (fmu, other):
    f.terminate()
    f.freeInstance()
json.dump(result, open(out_path, "w"))
print("ok")
