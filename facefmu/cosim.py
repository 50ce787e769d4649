r"""A fixed-step co-simulation master for FMI 2.0 co-simulation FMUs, through fmpy.

    from facefmu.cosim import Master, read_system
    system = read_system("OspSystemStructure.xml")      # simulators, connections, step
    with Master(system) as master:
        result = master.run(0.95, parameters={"control": {"targets_file": "t.json"}})
    result.rows          # one dict per communication step: "time" and the records

The system is declared, not coded: an OSP system structure (libcosim's XML: simulators
with their FMU and initial values, variable connections, the base step) read by
`read_system`, or a `System` made in code. So any controller FMU whose variables are
connected to FaceFMU's in the description runs, whatever its variable names.

Stepping (Jacobi, as libcosim's fixedStep algorithm and SSP's co-simulation master do):
at each communication point t every connection's value is read from its source and set
on its destination, then the utterance's own inputs (an open-loop schedule, `inputs`) are
set, then every simulator steps from t to t + h. A simulator's outputs at t therefore
act on the others over [t, t + h].

Records: each row holds "time" (t + h, the step's end) and the recorded variables, each
sampled either at the step's start ("@start": the value applied over the step, e.g. a
controller's commands) or at its end (the response, e.g. the face's lip outputs).

Instances: a Master instantiates each FMU once and keeps it between runs. A run whose
parameters for a simulator equal the last run's restores the state stored right after
its initialization (fmi2SetFMUstate, where the FMU can) and so skips the model's build;
other parameters reset it (fmi2Reset) and initialize it again; an instance that failed
with an error is freed and instantiated anew. A run that fails (a step the FMU discards,
an error, an exception) comes back as a Result with ``ok`` False and the reason, the
FMU's own log message included; the master stays usable.

This module imports no solver code: an FMU that bundles its own copy of the solver
(FaceFMU) imports that one in this process.
"""

import atexit
import ctypes
import math
import os
import shutil
import time
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

_OSP = "{http://opensimulationplatform.com/MSMI/OSPSystemStructure}"


@dataclass(frozen=True)
class Connection:
    """The value of source = (simulator, variable) is set on target = (simulator,
    variable) at every communication point."""
    source: tuple
    target: tuple


@dataclass
class System:
    """simulators: {name: FMU path}; initial: {name: {variable: value}} (parameters and
    start values set in initialization mode); connections: [Connection]; step: the
    communication step (s); start: the start time (s)."""
    simulators: dict
    connections: list = field(default_factory=list)
    initial: dict = field(default_factory=dict)
    step: float = 0.005
    start: float = 0.0

    def __post_init__(self):
        self.simulators = {k: str(Path(v).resolve()) for k, v in self.simulators.items()}
        for c in self.connections:
            for sim, _ in (c.source, c.target):
                if sim not in self.simulators:
                    raise ValueError(f"connection {c.source} -> {c.target}: no simulator "
                                     f"named {sim!r} (have {sorted(self.simulators)})")
        for name in self.initial:
            if name not in self.simulators:
                raise ValueError(f"initial values for {name!r}: no such simulator")
        if not (math.isfinite(self.step) and self.step > 0):
            raise ValueError(f"communication step {self.step!r} must be > 0")

    def with_fmus(self, **paths):
        """A copy with some simulators' FMU paths replaced."""
        return System({**self.simulators, **paths}, list(self.connections),
                      {k: dict(v) for k, v in self.initial.items()}, self.step, self.start)


def _value(element):
    """The typed value of an OSP <InitialValue>'s child (<Real value=...> etc.)."""
    for child in element:
        kind = child.tag.replace(_OSP, "")
        raw = child.get("value")
        if kind == "Real":
            return float(raw)
        if kind == "Integer":
            return int(raw)
        if kind == "Boolean":
            return raw.strip().lower() in ("true", "1")
        if kind == "String":
            return raw
    raise ValueError(f"initial value of {element.get('variable')!r} has no typed child")


def read_system(path, fmus=None):
    """A System from an OSP system structure file (OspSystemStructure.xml). FMU sources
    are relative to the file's folder; fmus ({simulator: path}) replaces some of them
    (e.g. FMUs built elsewhere). Raises ValueError naming what is wrong."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise ValueError(f"{path}: not a readable OSP system structure ({exc})") from None
    if root.tag != _OSP + "OspSystemStructure":
        raise ValueError(f"{path}: the root element is {root.tag!r}, not OspSystemStructure")
    sims, initial = {}, {}
    for s in root.iter(_OSP + "Simulator"):
        name, source = s.get("name"), s.get("source")
        if not name or not source:
            raise ValueError(f"{path}: a Simulator lacks its name or source")
        sims[name] = (fmus or {}).get(name) or path.parent / source
        values = {iv.get("variable"): _value(iv) for iv in s.iter(_OSP + "InitialValue")}
        if values:
            initial[name] = values
    conns = []
    for c in root.iter(_OSP + "VariableConnection"):
        ends = [(v.get("simulator"), v.get("name")) for v in c.findall(_OSP + "Variable")]
        if len(ends) != 2:
            raise ValueError(f"{path}: a VariableConnection needs two Variables")
        conns.append(Connection(*ends))
    step = root.findtext(_OSP + "BaseStepSize")
    start = root.findtext(_OSP + "StartTime")
    return System(sims, conns, initial, float(step) if step else 0.005,
                  float(start) if start else 0.0)


@dataclass(frozen=True)
class Record:
    """A recorded variable: column name, simulator, variable, and when it is sampled
    ("start" or "end" of the step)."""
    column: str
    simulator: str
    variable: str
    at: str = "end"

    @classmethod
    def parse(cls, text):
        """'[column=]simulator.variable[@start|@end]' -> Record (column: the variable)."""
        column, _, rest = text.rpartition("=")
        rest, _, at = rest.partition("@")
        sim, _, var = rest.partition(".")
        if not sim or not var or at not in ("", "start", "end"):
            raise ValueError(f"record {text!r} is not [column=]simulator.variable[@start|@end]")
        return cls(column or var, sim, var, at or "end")


@dataclass
class Result:
    """One run: rows (dicts per step, see the module docstring), ok, reason ("" when ok),
    wall (s), stop (s of simulated time asked for), logs ([(simulator, status, message)]
    of warnings and worse)."""
    rows: list
    ok: bool = True
    reason: str = ""
    wall: float = 0.0
    stop: float = 0.0
    logs: list = field(default_factory=list)

    @property
    def rtf(self):
        """Real-time factor: wall time per simulated second."""
        return self.wall / self.stop if self.stop else math.nan


_STATUS = ("ok", "warning", "discard", "error", "fatal", "pending")


def describe(path):
    """(fmpy model description, {variable name: ScalarVariable}) of an FMU; ValueError
    where it cannot be read or is not for co-simulation."""
    from fmpy import read_model_description
    try:
        md = read_model_description(str(path))
    except Exception as exc:
        raise ValueError(f"{path}: not a readable FMU ({exc})") from None
    if md.coSimulation is None:
        raise ValueError(f"{path}: not a co-simulation FMU")
    return md, {v.name: v for v in md.modelVariables}


_EXTRACTED = {}


def _extracted(path):
    """The folder an FMU is extracted to, once per process and FMU: the modules an FMU
    imports from its resources stay importable from there (a Python FMU imports lazily),
    so the folder is removed only at the process's exit."""
    from fmpy import extract
    key = (str(path), os.path.getmtime(path))
    if key not in _EXTRACTED:
        if not _EXTRACTED:
            atexit.register(lambda: [shutil.rmtree(d, ignore_errors=True)
                                     for d in _EXTRACTED.values()])
        _EXTRACTED[key] = extract(str(path))
    return _EXTRACTED[key]


class _Instance:
    """One FMU instance with its model description, value references, the log messages
    it sent, and the state stored after its last initialization."""

    def __init__(self, name, path, sink):
        self.name, self.path, self.sink = name, path, sink
        self.md, self.vars = describe(path)
        self.unzipped = _extracted(path)
        self.fmu = None
        self.params = None          # the parameters of the last initialization
        self.initial = None         # the FMU state right after it (where supported)
        self._callbacks = None

    def _variable(self, name):
        try:
            return self.vars[name]
        except KeyError:
            raise ValueError(f"simulator {self.name!r} ({Path(self.path).name}) has no "
                             f"variable {name!r}") from None

    def _logger(self):
        from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
        from fmpy.fmi1 import calloc, free

        # the instance named by the message, not self: pythonfmu's wrapper calls the
        # callbacks of the FMU instantiated last for every Python FMU in the process
        def log(env, instance, status, category, message):
            self.sink(instance.decode("utf-8", "replace") if instance else self.name,
                      _STATUS[status] if 0 <= status < 6 else str(status),
                      message.decode("utf-8", "replace"))

        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(log)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        try:                                # fmpy's proxy formats the FMU's printf messages
            from fmpy.logging import addLoggerProxy
            addLoggerProxy(ctypes.byref(cb))
        except Exception:
            pass
        return cb

    def start(self, params, t0):
        """Bring the instance to its initialized state at t0 with params ({variable:
        value}): restored where params are the last run's, else reset (or instantiated)
        and initialized."""
        from fmpy.fmi2 import FMU2Slave
        if self.fmu is not None and params == self.params and self.initial is not None:
            self.fmu.setFMUstate(self.initial)
            return
        if self.fmu is None:
            self._callbacks = self._logger()
            self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=self.unzipped,
                                 modelIdentifier=self.md.coSimulation.modelIdentifier,
                                 instanceName=self.name)
            self.fmu.instantiate(callbacks=self._callbacks, loggingOn=True)
        else:
            if self.initial is not None:
                self.fmu.freeFMUstate(self.initial)
            self.initial = self.params = None
            self.fmu.reset()
        self.fmu.setupExperiment(startTime=t0)
        self.fmu.enterInitializationMode()
        for name, value in params.items():
            self.set(name, value)
        self.fmu.exitInitializationMode()
        self.params = dict(params)
        if self.md.coSimulation.canGetAndSetFMUstate:
            self.initial = self.fmu.getFMUstate()

    def set(self, name, value):
        v = self._variable(name)
        vr = [v.valueReference]
        if v.type == "Real":
            self.fmu.setReal(vr, [float(value)])
        elif v.type in ("Integer", "Enumeration"):
            self.fmu.setInteger(vr, [int(value)])
        elif v.type == "Boolean":
            if isinstance(value, str):
                value = value.strip().lower() in ("true", "1", "yes")
            self.fmu.setBoolean(vr, [bool(value)])
        else:
            self.fmu.setString(vr, [str(value)])

    def get(self, name):
        v = self._variable(name)
        vr = [v.valueReference]
        if v.type == "Real":
            return self.fmu.getReal(vr)[0]
        if v.type in ("Integer", "Enumeration"):
            return self.fmu.getInteger(vr)[0]
        if v.type == "Boolean":
            return bool(self.fmu.getBoolean(vr)[0])
        s = self.fmu.getString(vr)[0]
        return s.decode() if isinstance(s, bytes) else s

    def close(self, terminate=True):
        """Terminate (unless after an error: the FMU is then only freed) and free."""
        if self.fmu is None:
            return
        try:
            if terminate:
                if self.initial is not None:
                    self.fmu.freeFMUstate(self.initial)
                self.fmu.terminate()
        except Exception:
            pass
        try:
            self.fmu.freeInstance()
        except Exception:
            pass
        self.fmu = self.initial = self.params = None


class Master:
    """Runs a System's co-simulations (module docstring), keeping its FMU instances
    between runs. records: Records or their text form (default: every connection's
    source, sampled at the step's end, as column 'simulator.variable'); echo: called
    with (simulator, status, message) for every message an FMU logs, as it comes."""

    def __init__(self, system, records=None, echo=None):
        self.system, self.echo = system, echo
        self.logs = []              # (simulator, status, message) of the current run
        if records is None:
            seen = dict.fromkeys(c.source for c in system.connections)
            records = [Record(f"{s}.{v}", s, v) for s, v in seen]
        self.records = [r if isinstance(r, Record) else Record.parse(r) for r in records]
        for r in self.records:
            if r.simulator not in system.simulators:
                raise ValueError(f"record {r.column!r}: no simulator named {r.simulator!r}")
        self._instances = {}

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        """Terminate and free every instance."""
        for inst in self._instances.values():
            inst.close()
        self._instances = {}

    def _log(self, simulator, status, message):
        self.logs.append((simulator, status, message))
        if self.echo is not None:
            self.echo(simulator, status, message)

    def _instance(self, name):
        if name not in self._instances:
            self._instances[name] = _Instance(name, self.system.simulators[name], self._log)
        return self._instances[name]

    def run(self, stop, parameters=None, inputs=None):
        """Co-simulate from the system's start for `stop` seconds.

        parameters: {simulator: {variable: value}} over the system's initial values;
        inputs: {"simulator.variable": value or sequence of one value per step}, set after
        the connections at every step (an open-loop schedule). Returns a Result; a
        failure is reported in it, never raised, except for a system that is wrong (an
        unknown simulator or variable: ValueError)."""
        sys_, h = self.system, self.system.step
        n = int(round(stop / h))
        if not (math.isfinite(stop) and stop > 0 and n >= 1):
            raise ValueError(f"stop time {stop!r} s must cover at least one step of {h} s")
        params = {k: dict(v) for k, v in sys_.initial.items()}
        for name, values in (parameters or {}).items():
            if name not in sys_.simulators:
                raise ValueError(f"parameters for {name!r}: no such simulator")
            params.setdefault(name, {}).update(values)
        schedule = []
        for key, values in (inputs or {}).items():
            sim, _, var = key.partition(".")
            if sim not in sys_.simulators or not var:
                raise ValueError(f"input {key!r} is not simulator.variable of this system")
            seq = [values] * n if isinstance(values, (int, float, str, bool)) else list(values)
            if len(seq) < n:
                raise ValueError(f"input {key!r} has {len(seq)} values for {n} steps")
            schedule.append((sim, var, seq))
        rows, t = [], sys_.start
        self.logs = []
        t0 = time.perf_counter()
        inst = {}
        where = "initialization"
        try:
            for name in sys_.simulators:
                inst[name] = self._instance(name)
                where = f"initialization of {name!r}"
                inst[name].start(params.get(name, {}), t)
            starts = [r for r in self.records if r.at == "start"]
            ends = [r for r in self.records if r.at == "end"]
            for k in range(n):
                where = f"the step from t = {t:.6g} s"
                values = [inst[c.source[0]].get(c.source[1]) for c in sys_.connections]
                row = {r.column: inst[r.simulator].get(r.variable) for r in starts}
                for c, v in zip(sys_.connections, values):
                    inst[c.target[0]].set(c.target[1], v)
                for sim, var, seq in schedule:
                    inst[sim].set(var, seq[k])
                for name, i in inst.items():
                    where = f"{name!r}'s step from t = {t:.6g} s"
                    i.fmu.doStep(t, h)
                t = sys_.start + (k + 1) * h
                row.update((r.column, inst[r.simulator].get(r.variable)) for r in ends)
                rows.append({"time": t, **{r.column: row[r.column] for r in self.records}})
            ok, reason = True, ""
        except ValueError:
            raise
        except Exception as exc:
            ok = False
            said = [m for m in self.logs if m[1] not in ("ok", "warning")]
            first = said[0] if said else None   # the cause, before the wrapper's own report
            reason = f"{where}: {exc}" + (f" ({first[0]}: {first[2]})" if first else "")
            if getattr(exc, "status", 3) >= 3:  # an error leaves the instances unusable
                for name, i in inst.items():
                    i.close(terminate=False)
                    self._instances.pop(name, None)
        logs = [m for m in self.logs if m[1] != "ok"]
        return Result(rows, ok, reason, time.perf_counter() - t0, stop, logs)


def cosimulate(system, stop, parameters=None, inputs=None, records=None):
    """One run of system on a fresh Master (its instances freed after): a Result."""
    with Master(system, records) as master:
        return master.run(stop, parameters, inputs)
