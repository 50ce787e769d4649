"""Independent simulations in parallel through dask.distributed: a sweep runner.

    from solver.sweep import Sweep
    tasks = [{"label": "coarse", "level": "coarse"}, {"label": "paper", "level": "paper"}]
    with Sweep() as sweep:                      # LocalCluster: 2 one-thread worker processes
        results = sweep.run(tasks, scene="rounding_u")
    with Sweep(scheduler="tcp://host:8786") as sweep:     # a running cluster
        ...

A task is a dict: a "label" and keyword arguments of solver.entry.open_simulation (Scene
fields such as level, half, substep_tol; "fidelity" for a preset, or "realtime"; "anatomy"
takes the path of an ANSYS face folder as the workers see it). The scene is a built-in name, a TOML path
or a dict as solver.app.scene.parse_scene takes; it ships as plain data with every task. Each
task runs in a worker process (`run_task`) and returns plain data with its own timing and
peak memory. A task that raises, or whose worker dies, comes back with its error message
instead of failing the sweep. A worker imports the simulation code with its first task;
dask.distributed comes with the package's `sweep` extra.

Workers are processes with one task at a time: the solver holds the GIL between numba
kernels. numba runs `numba_threads` threads per task (set in the task, so this holds on any
cluster); dask's nanny starts local workers with OMP, MKL and OpenBLAS at one thread. Two
one-thread tasks on two cores share memory bandwidth and caches: a wall time is that of a
run on one core next to another run (and next to whatever else loads the machine; cpu_s,
the worker's CPU time, is less sensitive to that).

numba: the kernels are compiled once into the shared cache (~/.cache/facefmu/numba). Before
the first sweep `Sweep.warmup` runs a 10 ms coarse task on one worker (which compiles into
the cache if it is cold), then on the others (which load from it): no worker compiles in a
timed task and two workers never compile the same kernels at once.

Remote clusters: the workers must have the package installed (with its `sweep` extra);
paths in tasks (anatomy folders, scene files) are read by the workers.

Peak memory (peak_mb): measured in the worker on Linux from /proc/self/status: the peak
resident set (VmHWM) is reset before each task by writing 5 to /proc/self/clear_refs and
read after it, minus the resident set at the start; so a task sees its own peak whatever
ran before in that process. Where the reset is refused it falls back to the growth of
resource.getrusage ru_maxrss, which is 0 when an earlier task in the process peaked higher
(memory_method says which).
"""

import os
import resource
import time

from solver.app.extras import need


def _status_mb(key):
    """A size field of /proc/self/status (VmRSS, VmHWM) in MiB."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith(key + ":"):
                return int(line.split()[1]) / 1024.0
    raise KeyError(key)


def _reset_peak():
    """Reset this process's peak resident set; False where the kernel refuses."""
    try:
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _maxrss_mb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0     # KiB on Linux


def run_task(task, scene="default", numba_threads=1):
    """Run one task in this process; plain data back.

    task: {"label": str, **open_simulation keyword arguments}; scene: built-in name, TOML
    path or scene dict; numba_threads: numba threads for the task. Returns a dict with
        label, kwargs (the task without its label), worker ("host:pid"), error ("" if none),
        ndof, bricks, volume_mm3 (reference volume of the mesh),
        build_s (open_simulation), wall_s and cpu_s (wall and process CPU time of
        Simulation.run()), simulated_s, rtf = wall_s / simulated_s,
        peak_mb (the task's peak resident set above its start, MiB), memory_method
        ("vmhwm" or "ru_maxrss"), rows (Simulation.run's records: time, outputs, activations).
    """
    import numba

    from solver.entry import open_simulation
    from solver.app.scene import parse_scene
    from solver.app.simulation import resolve_scene

    numba.set_num_threads(min(numba_threads, numba.config.NUMBA_NUM_THREADS))
    kwargs = {k: v for k, v in task.items() if k != "label"}
    out = {"label": task.get("label", ""), "kwargs": kwargs, "error": "",
           "worker": f"{os.uname().nodename}:{os.getpid()}"}
    vmhwm = _reset_peak()
    out["memory_method"] = "vmhwm" if vmhwm else "ru_maxrss"
    start_mb = _status_mb("VmRSS") if vmhwm else _maxrss_mb()
    try:
        base = parse_scene(scene) if isinstance(scene, dict) else resolve_scene(scene)
        t0 = time.perf_counter()
        sim = open_simulation(base, **kwargs)
        t1, c1 = time.perf_counter(), time.process_time()
        rows = sim.run()
        t2, c2 = time.perf_counter(), time.process_time()
    except Exception as exc:                       # reported per task, the sweep goes on
        out["error"] = f"{type(exc).__name__}: {exc}"
        return out
    peak_mb = _status_mb("VmHWM") if vmhwm else _maxrss_mb()
    mesh = sim.anatomy.mesh
    duration = float(sim.scene.duration)
    out.update(ndof=int(sim.face.model.system().ndof), bricks=int(mesh.n_bricks),
               volume_mm3=float(mesh.volumes.sum()), build_s=t1 - t0, wall_s=t2 - t1,
               cpu_s=c2 - c1, simulated_s=duration, rtf=(t2 - t1) / duration,
               peak_mb=max(peak_mb - start_mb, 0.0), rows=rows)
    sim.release()
    return out


class DaskClient:
    """A dask client on a LocalCluster of n_workers one-thread worker processes (the
    default; env: environment variables of the workers), or on the running cluster at
    `scheduler` (an address: tcp://host:8786). A context manager that closes both."""

    def __init__(self, scheduler=None, n_workers=2, env=None):
        need("dask.distributed", "sweep", "solver.sweep")
        from dask.distributed import Client, LocalCluster

        self.cluster = None
        if scheduler is None:
            self.cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1,
                                        processes=True, dashboard_address=None,
                                        env=dict(env or {}))
            self.client = Client(self.cluster)
        else:
            self.client = Client(scheduler)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self):
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()

    @property
    def workers(self):
        return list(self.client.scheduler_info()["workers"])


class Sweep(DaskClient):
    """A DaskClient for sweeps of scenes; numba_threads: numba threads per task."""

    def __init__(self, scheduler=None, n_workers=2, numba_threads=1):
        super().__init__(scheduler, n_workers)
        self.numba_threads = numba_threads
        self._warm = False

    def _submit(self, task, scene, **kw):
        return self.client.submit(run_task, task, scene, self.numba_threads, pure=False, **kw)

    def warmup(self, scene):
        """10 ms of scene on the coarse generic half face: on one worker, then the others."""
        task = {"label": "warmup", "anatomy": "generic", "level": "coarse", "half": True,
                "duration": 0.01, "interval": 0.01}
        first, *rest = self.workers
        for group in ([first], rest):
            for f in [self._submit(task, scene, workers=[w], allow_other_workers=False)
                      for w in group]:
                r = f.result()
                if r["error"]:
                    raise RuntimeError(f"warm-up task failed: {r['error']}")
        self._warm = True

    def run(self, tasks, scene="default", progress=True):
        """Run tasks (dicts: label and open_simulation keyword arguments) of scene; their
        results (see run_task) in the order of tasks. Tasks are submitted in list order (dask starts
        them roughly so): put the long ones first."""
        from dask.distributed import as_completed

        if not self._warm:
            self.warmup(scene)
        futures = {self._submit(t, scene): i for i, t in enumerate(tasks)}
        results = [None] * len(tasks)
        t0 = time.perf_counter()
        for done, f in enumerate(as_completed(futures), 1):
            i = futures[f]
            try:
                r = f.result()
            except Exception as exc:               # the worker died (memory, signal)
                r = {"label": tasks[i].get("label", ""), "kwargs": tasks[i],
                     "error": f"{type(exc).__name__}: {exc}"}
            results[i] = r
            if progress:
                what = r["error"] or (f"{r['wall_s']:.1f} s wall, {r['ndof']} dof, "
                                      f"{r['peak_mb']:.0f} MB")
                print(f"[{done}/{len(tasks)} {time.perf_counter() - t0:5.0f} s] "
                      f"{r['label']}: {what}", flush=True)
        return results
