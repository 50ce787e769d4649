"""Build FaceFMU and the LipMotorControl FMU, connect them, and co-simulate a speech
gesture /a/ -> /u/ -> /i/ -> /p/ through fmpy.

    python examples/cosim_speech.py [--stop 0.7] [--step 0.005] [--out out/cosim]

The controller's ten activations drive the face; the face's lip aperture and protrusion
feed back to the controller. Prints achieved against target per phoneme (at the end of
each target's window) and writes a CSV and a PNG of targets, outputs and activations.
"""

import argparse
import csv
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent


def build_fmus(dest):
    """Build both FMUs in a child process: building imports the slave scripts, and a
    solver package imported here would shadow the FMU's own copy at run time."""
    import subprocess
    subprocess.run([sys.executable, str(ROOT / "build_fmu.py"), "--dest", str(dest)],
                   check=True, stdout=subprocess.DEVNULL)
    subprocess.run([sys.executable, "-m", "pythonfmu", "build", "-f",
                    str(HERE / "motor_control" / "lip_motor_control.py"), "-d", str(dest),
                    "--no-external-tool"], check=True, stdout=subprocess.DEVNULL)
    return dest / "FaceFMU.fmu", dest / "LipMotorControl.fmu"


def instantiate(path, name, start_values=None):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    md = read_model_description(str(path))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu.enterInitializationMode()
    for key, value in (start_values or {}).items():
        if isinstance(value, str):
            fmu.setString([vr[key]], [value])
        elif isinstance(value, bool):
            fmu.setBoolean([vr[key]], [value])
        else:
            fmu.setReal([vr[key]], [value])
    fmu.exitInitializationMode()
    return fmu, vr


def cosimulate(face_fmu, control_fmu, stop, step, face_params=None, progress=True):
    """Step both FMUs together; returns a list of row dicts."""
    from tqdm import tqdm
    sys.path.insert(0, str(HERE / "motor_control"))
    from lip_motor_control import MUSCLES
    face, fv = instantiate(face_fmu, "face", face_params)
    ctrl, cv = instantiate(control_fmu, "control")
    rows, t = [], 0.0
    n = int(round(stop / step))
    for _ in tqdm(range(n), desc="co-simulation", unit="step", disable=not progress):
        ap, pr = face.getReal([fv["lip_aperture"], fv["lip_protrusion"]])
        ctrl.setReal([cv["lip_aperture"], cv["lip_protrusion"]], [ap, pr])
        ctrl.doStep(t, step)
        acts = ctrl.getReal([cv[m] for m in MUSCLES])
        face.setReal([fv[m] for m in MUSCLES], acts)
        face.doStep(t, step)
        t += step
        ap, pr, width = face.getReal([fv["lip_aperture"], fv["lip_protrusion"], fv["lip_width"]])
        tap, tpr = ctrl.getReal([cv["target_aperture"], cv["target_protrusion"]])
        phon = ctrl.getString([cv["phoneme"]])[0]
        rows.append({"time": t, "phoneme": phon.decode() if isinstance(phon, bytes) else phon,
                     "target_aperture": tap, "target_protrusion": tpr, "lip_aperture": ap,
                     "lip_protrusion": pr, "lip_width": width, **dict(zip(MUSCLES, acts))})
    for f in (face, ctrl):
        f.terminate()
        f.freeInstance()
    return rows


def summary(rows):
    """Achieved against target at the end of each phoneme's window."""
    last = {}
    for r in rows:
        last[r["phoneme"]] = r
    lines = ["phoneme  target ap  achieved ap  target pr  achieved pr   (mm)"]
    for ph, r in last.items():
        lines.append(f"  /{ph}/     {r['target_aperture']:7.2f}  {r['lip_aperture']:10.2f}  "
                     f"{r['target_protrusion']:9.2f}  {r['lip_protrusion']:10.2f}")
    return "\n".join(lines)


def plot(rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    t = [r["time"] for r in rows]
    fig, ax = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    for key, c in (("aperture", "C0"), ("protrusion", "C1")):
        ax[0 if key == "aperture" else 1].plot(t, [r[f"target_{key}"] for r in rows], "--",
                                              color=c, label=f"target {key}")
        ax[0 if key == "aperture" else 1].plot(t, [r[f"lip_{key}"] for r in rows], color=c,
                                              label=f"lip {key}")
    muscles = [k for k in rows[0] if k.isupper()]
    for m in muscles:
        if max(r[m] for r in rows) > 0.01:
            ax[2].plot(t, [r[m] for r in rows], label=m)
    ax[0].set_ylabel("aperture (mm)")
    ax[1].set_ylabel("protrusion (mm)")
    ax[2].set_ylabel("activation")
    ax[2].set_xlabel("time (s)")
    for a in ax:
        a.legend(loc="upper right", fontsize=8, ncol=3)
        a.grid(alpha=0.3)
    starts, seen = [], set()
    for r in rows:
        if r["phoneme"] not in seen:
            seen.add(r["phoneme"])
            starts.append((r["time"], r["phoneme"]))
    for ts, ph in starts:
        ax[0].annotate(f"/{ph}/", (ts, 1.0), xycoords=("data", "axes fraction"), va="top")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stop", type=float, default=0.7)
    ap.add_argument("--step", type=float, default=0.005)
    ap.add_argument("--out", default=str(ROOT / "out" / "cosim"))
    ap.add_argument("--level", default="coarse")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    face_fmu, control_fmu = build_fmus(out)
    print(f"built {face_fmu.name} and {control_fmu.name} in {time.perf_counter() - t0:.1f} s")
    t0 = time.perf_counter()
    rows = cosimulate(face_fmu, control_fmu, args.stop, args.step, {"level": args.level})
    wall = time.perf_counter() - t0
    print(f"co-simulated {args.stop} s in {wall:.1f} s of wall time "
          f"({args.step * 1e3:g} ms communication steps)")
    print(summary(rows))
    with open(out / "cosim.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    plot(rows, out / "cosim.png")
    print(f"wrote {out / 'cosim.csv'} and {out / 'cosim.png'}")


if __name__ == "__main__":
    main()
