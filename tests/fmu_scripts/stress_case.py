"""Stress cases through the built FMU with fmpy, in a fresh process (no `solver` import
here: the FMU's bundled copy must be the one that runs).

    python stress_case.py FMU OUT.json CASES.json

CASES.json: a list of {"name", "scene" (TOML path), "tolerance", "max_substep",
"steps": [[s, {muscle: a, jaw input: value}], ...], "memory": bool}. For each case, one FMU
instance steps like a master: set all ten activations and the jaw inputs, doStep; a step answered with fmi2Discard is
recorded and the master goes on from the same time. OUT.json: per case the status of
each step, the outputs after it, and the resident memory (MB) at 10 % and at the end;
init_status where initialization failed.
"""

import json
import os
import sys
import time

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import FMU2Slave

LIP = ["lip_aperture", "lip_protrusion", "lip_width", "upper_lip_protrusion",
       "lower_lip_protrusion"]
MUSCLES = ["LLSAN", "LAO", "ZYG", "RIS", "BUC", "DAO", "DLI", "MENT", "OOP", "OOM"]
JAW = ["jaw_opening", "jaw_protrusion"]


def rss_mb():
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20


def set_inputs(fmu, vr, refs, acts):
    """All ten activations (0 where absent) and the jaw inputs the FMU has (likewise)."""
    fmu.setReal(refs, [float(acts.get(m, 0.0)) for m in MUSCLES])
    jaw = [k for k in JAW if k in vr]
    fmu.setReal([vr[k] for k in jaw], [float(acts.get(k, 0.0)) for k in jaw])


def run(md, unzip, vr, case):
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzip,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=case["name"])
    fmu.instantiate(loggingOn=True)
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.setString([vr["scene"], vr["fidelity"], vr["anatomy"]],
                  [case["scene"], case.get("fidelity", ""), case.get("anatomy", "generic")])
    if not case.get("fidelity"):                # a preset sets them itself
        fmu.setString([vr["level"]], [case.get("level", "coarse")])
        fmu.setBoolean([vr["half_face"]], [case.get("half", True)])
        fmu.setReal([vr["tolerance"], vr["max_substep"]],
                    [case["tolerance"], case["max_substep"]])
    try:
        fmu.exitInitializationMode()
    except FMICallException as exc:             # e.g. a realtime fidelity with no model
        fmu.freeInstance()
        return {"rows": [], "statuses": [], "memory": {}, "rollback": {}, "wall": 0.0,
                "init_status": exc.status}
    refs = [vr[m] for m in MUSCLES]
    out_refs = [vr[k] for k in LIP]
    stats = [k for k in ("newton_iterations", "substeps", "cutbacks") if k in vr]
    stat_refs = [vr[k] for k in stats]                 # cutbacks: where the FMU has it
    t, rows, statuses, mem = 0.0, [], [], {}
    n = len(case["steps"])
    wall = time.perf_counter()
    for k, (h, acts) in enumerate(case["steps"]):
        if case.get("memory") and k == max(1, n // 10):
            mem["start"] = rss_mb()
        before = fmu.getReal(out_refs)
        set_inputs(fmu, vr, refs, acts)
        try:
            fmu.doStep(t, h)
            status = 0
        except FMICallException as exc:
            status = exc.status
        values = fmu.getReal(out_refs)
        counts = dict(zip(stats, fmu.getInteger(stat_refs)))
        statuses.append(status)
        if status == 0:
            t += h
            rows.append(dict(zip(LIP, values), t=t, **counts))
        else:
            rows.append({"refused": True, "unchanged": values == before})
    rollback = {}
    if case.get("rollback") and all(s == 0 for s in statuses):
        h, acts = case["steps"][-1]
        state, first = fmu.getFMUstate(), None
        rollback = {"repeats": 0, "identical": True}
        for i in range(case["rollback"]):
            fmu.setFMUstate(state)
            set_inputs(fmu, vr, refs, acts)
            try:
                fmu.doStep(t, h)
            except FMICallException as exc:
                rollback.update(identical=False, problem=f"repeat {i}: status {exc.status}")
                break
            values = fmu.getReal(out_refs)
            first = first or values
            rollback["repeats"] = i + 1
            if values != first:
                rollback.update(identical=False, problem=f"repeat {i}: {values} != {first}")
                break
        fmu.setFMUstate(state)
        fmu.freeFMUstate(state)
    if case.get("memory"):
        mem["end"] = rss_mb()
    fmu.terminate()
    fmu.freeInstance()
    return {"rows": rows, "statuses": statuses, "memory": mem, "rollback": rollback,
            "wall": time.perf_counter() - wall}


fmu_path, out_path, cases_path = sys.argv[1:4]
md = read_model_description(fmu_path)
vr = {v.name: v.valueReference for v in md.modelVariables}
unzip = extract(fmu_path)
results = {}
for case in json.load(open(cases_path)):
    results[case["name"]] = run(md, unzip, vr, case)
    print(f"{case['name']}: {results[case['name']]['wall']:.1f} s", flush=True)
json.dump(results, open(out_path, "w"))
print("ok")
