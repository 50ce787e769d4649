"""FMU life-cycle faults, in a fresh process (no `solver` import here):

    python fault_lifecycle.py FMU OUT.json BAD_SCENE MISSING_FOLDER [BAD_FOLDER]

* re-instantiation: a second instance after the first was freed gives the same outputs;
* fmi2Reset in the middle of a run (no terminate) and after terminate: the instance
  starts again from rest, inputs back at their start values, and repeats the run exactly;
* freeInstance in the middle of a run (no terminate), right after instantiate, and right
  after a refused step: no crash, and an instance stepping alongside is not disturbed;
* unusable parameters (a corrupted scene file, a missing or corrupted anatomy folder):
  exitInitializationMode fails with a logged message, and a new instance in the same
  process then works.
Every instance runs the coarse generic face without a preset (BASE): the life cycle does
not depend on the mesh, and the coarse one initializes in a fraction of the default's time.
OUT.json holds what each check saw; the test judges it. Exit code 0 = no crash.
"""

import json
import sys

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

fmu_path, out_path, bad_scene, missing = sys.argv[1:5]
bad_folder = sys.argv[5] if len(sys.argv) > 5 else None
md = read_model_description(fmu_path)
vr = {v.name: v.valueReference for v in md.modelVariables}
unzip = extract(fmu_path)
OUT = ["lip_aperture", "lip_protrusion", "lip_width", "upper_lip_protrusion",
       "lower_lip_protrusion"]
DT = 0.001
BASE = {"fidelity": "", "level": "coarse"}


def new(name):
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzip,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    fmu.instantiate(loggingOn=True)
    return fmu


def initialize(fmu, strings=None):
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    for key, value in dict(BASE, **(strings or {})).items():
        fmu.setString([vr[key]], [value])
    fmu.exitInitializationMode()
    return fmu


def outputs(fmu):
    return fmu.getReal([vr[k] for k in OUT])


def steps(fmu, n, t0=0.0, oop=0.5):
    fmu.setReal([vr["OOP"]], [oop])
    for k in range(n):
        fmu.doStep(t0 + k * DT, DT)
    return outputs(fmu)


res = {}
# a reference run, then re-instantiation in the same process
ref = initialize(new("ref"))
res["rest"] = outputs(ref)
res["ref3"] = steps(ref, 3)
ref.terminate()
ref.freeInstance()
again = initialize(new("again"))
res["reinstantiated3"] = steps(again, 3)

# reset in the middle of a run (no terminate): back to rest, the run repeats exactly
steps(again, 2, t0=3 * DT)
again.reset()
res["oop_after_reset"] = again.getReal([vr["OOP"]])[0]
initialize(again)
res["rest_after_reset"] = outputs(again)
res["after_reset3"] = steps(again, 3)
# reset after terminate (the usual order)
again.terminate()
again.reset()
initialize(again)
res["after_terminate_reset3"] = steps(again, 3)
again.terminate()
again.freeInstance()

# freeInstance in the middle of a run, beside another instance
a, b = initialize(new("a")), initialize(new("b"))
steps(a, 2)
steps(b, 2)
a.freeInstance()                           # mid-run, without terminate
res["beside_freed3"] = steps(b, 1, t0=2 * DT)
b.freeInstance()                           # also without terminate
lonely = new("never_initialized")
lonely.freeInstance()                      # right after instantiate
refused = initialize(new("refused"))
refused.setReal([vr["OOP"]], [float("nan")])
try:
    refused.doStep(0.0, DT)
    res["nan_status"] = 0
except FMICallException as exc:
    res["nan_status"] = exc.status
refused.freeInstance()                     # right after a refused step

# unusable parameters: a clear failure at initialization, then a good instance works
res["bad_parameters"] = {}
bad = [("scene", bad_scene), ("anatomy", missing)] + ([("anatomy", bad_folder)]
                                                     if bad_folder else [])
for key, value in bad:
    fmu = new(f"bad_{key}")
    try:
        initialize(fmu, {key: value})
        res["bad_parameters"][value] = 0
    except FMICallException as exc:
        res["bad_parameters"][value] = exc.status
    fmu.freeInstance()
good = initialize(new("good"))
res["then3"] = steps(good, 3)
good.terminate()
good.freeInstance()
json.dump(res, open(out_path, "w"))
print("ok")
