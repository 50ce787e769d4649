r"""Honest accuracy of a realtime model: held-out gestures, reduced against full order.

Gestures (none is a training pattern; training draws random patterns, solver.rom.train):

* oop_ris (0.3 s): OOP 0 -> 1 and RIS 0 -> 0.5 ramps over 0-0.15 s, held;
* open (0.3 s): LLSAN and DLI 0 -> 0.8 over 0-0.1 s, held, back to 0.2 over 0.15-0.25 s;
* open_round (0.1 s): LLSAN, DLI 0 -> 0.8 over 0-0.04 s, then OOP 0 -> 0.6 and
  RIS 0 -> 0.5 over 0.04-0.08 s (the gesture of benchmarks/accuracy_vs_time.py);
* jaw_vowel (0.3 s): the jaw opens 0 -> 8 deg (12 mm at the incisors) with LLSAN and DLI
  0 -> 0.5 over 0-0.1 s, then closes to 3 deg while OOP 0 -> 0.6 over 0.15-0.25 s (an
  open vowel, then a rounded one).

Each runs with the reduced model (caller steps of `rom_step`, 5 ms: as the main job's
FMU master) and with the full-order model of the same scene (the realtime knobs:
coarse generic half face, loose tolerances; caller steps of `full_step`), both from rest.
Errors: over the full run's record times, max and RMS of |ROM - full| in lip aperture
and lip protrusion (mm, Simulation.outputs()). Times: wall and process CPU time of the
stepping (build apart); rtf = wall / simulated time.
"""

import time

import numpy as np

from solver.app.scene import Schedule
from solver.rom.train import drive


def _ramp(m, t0, t1, a, b):
    return Schedule(m, "ramp", (t0, t1), (a, b))


def _pwl(m, times, values):
    return Schedule(m, "pwl", tuple(times), tuple(values))


GESTURES = {
    "oop_ris": (0.3, (_ramp("OOP", 0.0, 0.15, 0.0, 1.0), _ramp("RIS", 0.0, 0.15, 0.0, 0.5))),
    "open": (0.3, (_pwl("LLSAN", (0.0, 0.1, 0.15, 0.25), (0.0, 0.8, 0.8, 0.2)),
                   _pwl("DLI", (0.0, 0.1, 0.15, 0.25), (0.0, 0.8, 0.8, 0.2)))),
    "open_round": (0.1, (_ramp("LLSAN", 0.0, 0.04, 0.0, 0.8), _ramp("DLI", 0.0, 0.04, 0.0, 0.8),
                         _ramp("OOP", 0.04, 0.08, 0.0, 0.6), _ramp("RIS", 0.04, 0.08, 0.0, 0.5))),
    "jaw_vowel": (0.3, (_pwl("jaw_opening", (0.0, 0.1, 0.15, 0.25), (0.0, 8.0, 8.0, 3.0)),
                        _ramp("LLSAN", 0.0, 0.1, 0.0, 0.5), _ramp("DLI", 0.0, 0.1, 0.0, 0.5),
                        _ramp("OOP", 0.15, 0.25, 0.0, 0.6))),
}


def _timed(sim, schedules, duration, step):
    w0, c0 = time.perf_counter(), time.process_time()
    rows = drive(sim, schedules, duration, step)
    return rows, time.perf_counter() - w0, time.process_time() - c0


def compare(rom, full, gestures=None, rom_step=5e-3, full_step=5e-3, full_runs=None):
    """Rows (dicts) per gesture: errors (mm) and times (s). rom: a ReducedSimulation,
    full: the full-order Simulation of the same scene; both are reset to rest. full_runs:
    a dict {gesture: (rows, wall, cpu)} of full runs already made (filled here), so that
    several reduced models are compared with one full run per gesture."""
    out = []
    full_runs = {} if full_runs is None else full_runs
    zero_rom, zero_full = rom.get_state(), full.get_state()
    for name in gestures or GESTURES:
        duration, sched = GESTURES[name]
        for s in sched:
            if s.muscle not in rom.face.muscles and not s.muscle.startswith("jaw_"):
                raise ValueError(f"gesture {name}: muscle {s.muscle} is not driven")
        rom.set_state(zero_rom)
        rom.mode = "rom"
        full.set_state(zero_full)
        r_rows, r_wall, r_cpu = _timed(rom, sched, duration, rom_step)
        if name not in full_runs:
            full_runs[name] = _timed(full, sched, duration, full_step)
        f_rows, f_wall, f_cpu = full_runs[name]
        every = int(round(full_step / rom_step))
        r_rows = r_rows[::every]
        row = {"gesture": name, "duration_s": duration}
        for key, short in (("lip_aperture", "aperture"), ("lip_protrusion", "protrusion")):
            d = np.array([a[key] - b[key] for a, b in zip(r_rows, f_rows)])
            row[f"max_err_{short}_mm"] = float(np.abs(d).max())
            row[f"rms_err_{short}_mm"] = float(np.sqrt(np.mean(d ** 2)))
            row[f"full_range_{short}_mm"] = float(np.ptp([b[key] for b in f_rows]))
        rho = [x for t, x in rom.trust_history if t <= duration + 1e-9]
        row.update(rom_wall_s=r_wall, rom_cpu_s=r_cpu, rom_rtf=r_wall / duration,
                   rom_ms_per_step=1e3 * r_wall / round(duration / rom_step),
                   full_wall_s=f_wall, full_cpu_s=f_cpu, full_rtf=f_wall / duration,
                   rho_max=max(rho, default=float("nan")), fell_back=rom.mode == "full")
        rom.trust_history.clear()
        out.append(row)
    return out
