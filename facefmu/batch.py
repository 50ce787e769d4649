"""Batches of co-simulations on dask.distributed: one task per utterance.

    from facefmu.batch import Batch, from_targets
    from facefmu.cosim import read_system
    system = read_system("OspSystemStructure.xml")
    with Batch(system) as batch:                        # a LocalCluster of 2 workers
        result = batch.run(from_targets(["a.json", "b.json"]))
    result.write("out/batch")          # trajectories and summary, parquet or CSV
    Batch(system, scheduler="tcp://host:8786")          # a running cluster

An utterance is a co-simulation of the system (`Utterance`: a name, the simulated time,
parameters per simulator, an open-loop input schedule, and optionally speech targets to
score). `from_targets` makes one per target file (the controller's `targets_file`
parameter), `grid` one per point of a parameter grid over any simulators' parameters.

Workers: each worker process keeps one facefmu.cosim.Master per system, so its FMUs are
instantiated once and restored (or reset) between its tasks. Before the first batch the
solver's kernels are compiled into the shared cache (``python -m solver.app.warm``) on one
worker, then loaded by the others. Local workers run one thread each (numba, MKL, OpenMP,
OpenBLAS: the nanny's environment), so n workers use n cores.

Failures are contained: an utterance whose co-simulation fails (a step an FMU discards,
an error, a target file that cannot be read) is recorded with its reason and the batch
goes on; a task whose worker dies is rerun by dask on another worker (the nanny restarts
the dead one), up to dask's `distributed.scheduler.allowed-failures`, after which it is
recorded as failed.
"""

import atexit
import itertools
import math
import os
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

from facefmu import speech
from facefmu.cosim import Master

THREAD_ENV = {"NUMBA_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OMP_NUM_THREADS": "1",
              "OPENBLAS_NUM_THREADS": "1"}


@dataclass
class Utterance:
    """One co-simulation: name, stop (s of simulated time), parameters ({simulator:
    {variable: value}}), inputs (facefmu.cosim.Master.run's open-loop schedule), targets
    (a speech target list scored by facefmu.speech, or None), error (a problem found
    before running: the utterance is recorded as failed with it)."""
    name: str
    stop: float
    parameters: dict = field(default_factory=dict)
    inputs: dict = field(default_factory=dict)
    targets: list | None = None
    error: str = ""


def from_targets(paths, controller="control", parameter="targets_file"):
    """One Utterance per speech target file: its duration, the controller's parameter
    set to the file's absolute path. A file that cannot be read, or whose targets are
    not finite, gives an Utterance with its error."""
    out = []
    for p in paths:
        p = Path(p).resolve()
        try:
            targets = speech.load_targets(p)
            out.append(Utterance(p.stem, speech.duration(targets),
                                 {controller: {parameter: str(p)}}, targets=targets))
        except ValueError as exc:
            out.append(Utterance(p.stem, math.nan, error=str(exc)))
    return out


def grid(base, axes):
    """Utterances over the product of axes ({"simulator.variable": [values]}) on top of
    base's parameters; named base.name plus the point ("a[control.tau_fb=0.02]")."""
    keys = list(axes)
    out = []
    for point in itertools.product(*(axes[k] for k in keys)):
        params = {s: dict(v) for s, v in base.parameters.items()}
        for k, v in zip(keys, point):
            sim, _, var = k.partition(".")
            if not var:
                raise ValueError(f"grid axis {k!r} is not simulator.variable")
            params.setdefault(sim, {})[var] = v
        label = ",".join(f"{k}={v}" for k, v in zip(keys, point))
        out.append(Utterance(f"{base.name}[{label}]", base.stop, params, dict(base.inputs),
                             base.targets, base.error))
    return out


# -- in a worker ---------------------------------------------------------------------------

_MASTERS = {}


def _close_masters():
    for m in _MASTERS.values():
        m.close()
    _MASTERS.clear()


def _master(system, records):
    """This process's Master for system and records (made at its first task)."""
    key = repr((system, records))
    if key not in _MASTERS:
        if not _MASTERS:
            atexit.register(_close_masters)     # FMUs terminated while modules still exist
        _MASTERS[key] = Master(system, records)
    return _MASTERS[key]


def run_utterance(system, records, utt):
    """Run one utterance in this process (a worker): {"summary": dict, "rows": list}.
    The summary holds utterance, ok, reason, worker, steps, wall_s, simulated_s, rtf, and
    where the utterance has targets: targets, met and the largest error per output."""
    summary = {"utterance": utt.name, "ok": False, "reason": utt.error,
               "worker": f"{os.uname().nodename}:{os.getpid()}", "steps": 0,
               "wall_s": 0.0, "simulated_s": utt.stop, "rtf": math.nan}
    if utt.error:
        return {"summary": summary, "rows": []}
    try:
        res = _master(system, records).run(utt.stop, utt.parameters, utt.inputs)
    except Exception as exc:                    # a wrong system or input: this one fails
        summary["reason"] = f"{type(exc).__name__}: {exc}"
        return {"summary": summary, "rows": []}
    summary.update(ok=res.ok, reason=res.reason, steps=len(res.rows), wall_s=res.wall,
                   rtf=res.rtf)
    if utt.targets is not None and res.ok:
        results = speech.tracking(res.rows, utt.targets)
        summary.update(speech.summary(results))
        misses = [f"/{tg['phoneme']}/ {o} {c[2]:+.2f} mm" for tg, _, checks in results
                  for o, c in checks.items() if not c[4]]
        if misses:
            summary["reason"] = "targets missed: " + ", ".join(misses)
    return {"summary": summary, "rows": res.rows}


def _warm(cwd=None):
    """Compile the solver's kernels into the shared cache in a child process (non-fatal:
    (returncode, last line of its output))."""
    try:
        run = subprocess.run([sys.executable, "-m", "solver.app.warm", "--quiet"],
                             capture_output=True, text=True, cwd=cwd)
    except OSError as exc:
        return 1, str(exc)
    lines = (run.stdout + run.stderr).strip().splitlines()
    return run.returncode, lines[-1] if lines else ""


# -- the client ----------------------------------------------------------------------------

@dataclass
class BatchResult:
    """summary: one dict per utterance (run_utterance's), in the batch's order;
    trajectories: {utterance name: rows}."""
    summary: list
    trajectories: dict

    def tables(self):
        """(trajectory rows with an "utterance" column first, summary rows)."""
        traj = [{"utterance": name, **row} for name, rows in self.trajectories.items()
                for row in rows]
        return traj, self.summary

    def write(self, folder, fmt=None):
        """Write trajectories and summary into folder as parquet (where pyarrow imports;
        fmt "csv" or "parquet" forces one); returns the two paths."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        if fmt is None:
            try:
                import pyarrow  # noqa: F401
                fmt = "parquet"
            except ImportError:
                fmt = "csv"
        paths = []
        for name, rows in zip(("trajectories", "summary"), self.tables()):
            path = folder / f"{name}.{fmt}"
            if fmt == "parquet":
                import pyarrow as pa
                import pyarrow.parquet as pq
                pq.write_table(pa.Table.from_pylist(rows), path)
            else:
                import csv
                cols = list(dict.fromkeys(k for r in rows for k in r))
                with open(path, "w", newline="") as fh:
                    w = csv.DictWriter(fh, fieldnames=cols)
                    w.writeheader()
                    w.writerows(rows)
            paths.append(path)
        return paths


class Batch:
    """A dask client that runs utterances of one system: a LocalCluster of n_workers
    one-thread worker processes (the default), or the running cluster at scheduler."""

    def __init__(self, system, records=None, scheduler=None, n_workers=2):
        from solver.sweep import DaskClient     # client side only: workers import no solver
        self.system, self.records = system, records
        self._dask = DaskClient(scheduler, n_workers, THREAD_ENV)
        self.client = self._dask.client
        self._warm = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        try:
            self.client.run(_close_masters)     # terminate the FMUs before the workers go
        except Exception:
            pass
        self._dask.close()

    @property
    def workers(self):
        return self._dask.workers

    def warmup(self, log=print):
        """Compile the kernels on one worker into the shared cache, then let the others
        load them (non-fatal: a failure is logged)."""
        first, *rest = self.workers
        for group in ([first], rest):
            if not group:
                continue
            for addr, (code, line) in self.client.run(_warm, workers=group).items():
                if code:
                    log(f"kernel warm-up on {addr} failed ({line}); kernels compile in "
                        "the first task")
        self._warm = True

    def run(self, utterances, progress=True):
        """Run the utterances; a BatchResult in their order. Names must be unique."""
        from dask.distributed import as_completed
        names = [u.name for u in utterances]
        if len(set(names)) != len(names):
            raise ValueError("utterance names must be unique")
        if not self._warm:
            self.warmup()
        futures = {self.client.submit(run_utterance, self.system, self.records, u,
                                      pure=False, key=f"utterance-{i}-{u.name}"): i
                   for i, u in enumerate(utterances)}
        out = [None] * len(utterances)
        bar = _bar(len(utterances), progress)
        for f in as_completed(futures):
            i = futures[f]
            try:
                r = f.result()
            except Exception as exc:            # the task's workers died too often
                r = {"summary": {"utterance": names[i], "ok": False,
                                 "reason": f"{type(exc).__name__}: {exc}", "steps": 0,
                                 "wall_s": 0.0, "simulated_s": utterances[i].stop,
                                 "rtf": math.nan}, "rows": []}
            out[i] = r
            bar.update(1)
            if not r["summary"]["ok"] or r["summary"]["reason"]:
                bar.write(f"{names[i]}: {r['summary']['reason']}")
        bar.close()
        return BatchResult([r["summary"] for r in out],
                           {n: r["rows"] for n, r in zip(names, out)})


class _NoBar:
    def update(self, n):
        pass

    def write(self, text):
        pass

    def close(self):
        pass


def _bar(total, progress):
    if not progress:
        return _NoBar()
    try:
        from tqdm import tqdm
    except ImportError:
        return _NoBar()
    return tqdm(total=total, unit="utterance", desc="batch")


def run_batch(system, utterances, records=None, scheduler=None, n_workers=2, progress=True):
    """Batch(system, records, scheduler, n_workers).run(utterances), the cluster closed
    after."""
    with Batch(system, records, scheduler, n_workers) as batch:
        return batch.run(utterances, progress)


def _alone(system, records, utt):
    """run_utterance in a fresh process with the workers' one-thread environment."""
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context
    saved = {k: os.environ.get(k) for k in THREAD_ENV}
    os.environ.update(THREAD_ENV)           # a spawned process starts with this environment
    try:
        with ProcessPoolExecutor(1, mp_context=get_context("spawn")) as pool:
            return pool.submit(run_utterance, system, records, utt).result()
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def serial(system, utterances, records=None):
    """Each utterance alone: in a fresh process of its own, one thread, as a batch's
    worker runs (the reference a batch must reproduce). A BatchResult."""
    out = [_alone(system, records, u) for u in utterances]
    return BatchResult([r["summary"] for r in out],
                       {u.name: r["rows"] for u, r in zip(utterances, out)})
