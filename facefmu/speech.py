"""Speech targets on a co-simulation of FaceFMU with a motor controller: what to record,
and whether each target was met.

A target list is JSON: a list of {"phoneme", "duration" (s), "targeted" (output names),
"lip_aperture", "lip_protrusion", "lip_width" (mm), optionally "jaw_opening" (deg) and
"intent"}, or a dict holding one under "targets" (examples/motor_control/
inverse_model.json). A target is met when, at the end of its window, each targeted
output is within TOLERANCE of it.

`records(system)` records what the face was driven with and how it responded, whatever
the controller's variable names: every input of the face connected in the system (named
by the face's variable, sampled at the step's start: the value applied over the step),
the controller's published target and phoneme where it has them, and the face's lip
outputs and incisor opening at the step's end.
"""

import json
import math
from pathlib import Path

from facefmu.cosim import Record, describe

TOLERANCE = {"lip_aperture": 0.3, "lip_protrusion": 0.3, "lip_width": 0.5}     # mm
OUTPUTS = ("lip_aperture", "lip_protrusion", "lip_width")
TARGETS = {"lip_aperture": "target_aperture", "lip_protrusion": "target_protrusion",
           "lip_width": "target_width"}
FACE_ENDS = OUTPUTS + ("incisor_opening",)


def load_targets(path):
    """The target list of a JSON file (a list, or a dict's "targets"); ValueError naming
    the file and the first bad entry."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"targets file {path}: {exc}") from None
    targets = data["targets"] if isinstance(data, dict) else data
    for k, tg in enumerate(targets):
        d = tg.get("duration")
        if not (isinstance(d, (int, float)) and math.isfinite(d) and d > 0):
            raise ValueError(f"targets file {path}: target {k} has duration {d!r}")
        for o in tg.get("targeted", ()):
            if o not in OUTPUTS:
                raise ValueError(f"targets file {path}: target {k} targets {o!r}, not one "
                                 f"of {list(OUTPUTS)}")
            v = tg.get(o)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ValueError(f"targets file {path}: target {k} ({tg.get('phoneme')!r}) "
                                 f"has {o} = {v!r}, not a finite number (mm)")
    return targets


def duration(targets):
    """The targets' total duration (s)."""
    return sum(tg["duration"] for tg in targets)


def records(system, face="face"):
    """Records for a speech co-simulation of system (module docstring), in the column
    order: time, phoneme, targets, lip outputs, the face's connected inputs, incisor
    opening."""
    inputs = [(c.target[1], c.source) for c in system.connections if c.target[0] == face]
    sources = {s for _, (s, _) in inputs}
    out = []
    if len(sources) == 1:               # the controller's own target and phoneme
        ctrl = sources.pop()
        have = describe(system.simulators[ctrl])[1]
        out += [Record(v, ctrl, v, "start") for v in ("phoneme", *TARGETS.values())
                if v in have]
    have = describe(system.simulators[face])[1]
    out += [Record(o, face, o) for o in OUTPUTS]
    out += [Record(var, s, v, "start") for var, (s, v) in inputs]
    if "incisor_opening" in have:
        out.append(Record("incisor_opening", face, "incisor_opening"))
    return out


def tracking(rows, targets):
    """Per target, at the end of its window: [(target dict, time, {output: (target,
    achieved, error, tolerance, met)})] for the targeted outputs."""
    out, end = [], 0.0
    for tg in targets:
        end += tg["duration"]
        row = min(rows, key=lambda r: abs(r["time"] - end))
        checks = {}
        for o in OUTPUTS:
            if o in tg["targeted"]:
                err = row[o] - tg[o]
                checks[o] = (tg[o], row[o], err, TOLERANCE[o], abs(err) <= TOLERANCE[o])
        out.append((tg, row["time"], checks))
    return out


def missed(results):
    """The number of targets with an output outside its tolerance (NaN counts as out)."""
    return sum(not all(c[4] for c in checks.values()) for _, _, checks in results)


def summary(results):
    """{targets, met, largest error per output (mm)} of tracking's results."""
    errs = {o: max((abs(c[o][2]) for _, _, c in results if o in c), default=0.0)
            for o in OUTPUTS}
    return {"targets": len(results), "met": len(results) - missed(results),
            **{f"max_error_{o.split('_')[1]}": e for o, e in errs.items()}}


def table(results):
    """The tracking table as text."""
    lines = [f"{'target':8s}{'window end':12s}{'jaw deg':>8s}  {'output':16s}{'target':>8s}"
             f"{'achieved':>10s}{'error':>8s}{'tol':>6s}  result"]
    for tg, t, checks in results:
        for k, (o, (target, got, err, tol, met)) in enumerate(checks.items()):
            ph, end, jaw = (f"/{tg['phoneme']}/", f"{t:.3f} s",
                            f"{tg.get('jaw_opening', 0.0):.1f}") if k == 0 else ("", "", "")
            lines.append(f"{ph:8s}{end:12s}{jaw:>8s}  {o:16s}{target:8.2f}{got:10.2f}"
                         f"{err:+8.2f}{tol:6.1f}  {'met' if met else 'MISSED'}")
    return "\n".join(lines)
