"""The speech co-simulation of examples/cosim_speech.py in a second master: libcosim (the
Open Simulation Platform's co-simulation library, through libcosimpy), reading the system
from examples/motor_control/OspSystemStructure.xml; exit 1 if a target is missed or if
the run differs from fmpy's by more than 0.01 mm.

    python -m pip install libcosimpy
    python examples/cosim_libcosim.py [--out out/cosim_libcosim] [--targets FILE]
                                      [--compare CSV]

--targets: as for cosim_speech.py (written into the system structure's initial values);
--compare: the cosim.csv of an fmpy run of examples/cosim_speech.py with the same
targets (default: run it now, into OUT/fmpy, in its own process). Prints the tracking
table, the wall time, and the largest difference of the lip outputs between the masters.
"""

import argparse
import csv
import subprocess
import sys
import time
from pathlib import Path
from xml.sax.saxutils import escape

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from cosim_speech import (CONTROL, MUSCLES, OUTPUTS, TARGETS, build_fmus,  # noqa: E402
                          load_targets, report)

MATCH = 0.01        # mm


def cosimulate(folder, stop, step):
    """Run the OSP system in `folder` with libcosim; rows as cosim_speech.cosimulate."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver
    log_output_level(CosimLogLevel.WARNING)
    execution = CosimExecution.from_osp_config_file(str(folder / "OspSystemStructure.xml"))
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    face = execution.slave_index_from_instance_name("face")
    ctrl = execution.slave_index_from_instance_name("control")
    ref = {(s, v.name.decode()): v.reference for s in (face, ctrl)
           for v in execution.slave_variables(s)}
    execution.step(0)           # initialization (the FMUs' initial outputs)
    rows, t = [], 0.0
    for _ in range(int(round(stop / step))):
        acts = observer.last_real_values(ctrl, [ref[ctrl, m] for m in MUSCLES])
        opening = observer.last_real_values(ctrl, [ref[ctrl, "jaw_opening"]])[0]
        targets = observer.last_real_values(ctrl, [ref[ctrl, TARGETS[o]] for o in OUTPUTS])
        phoneme = observer.last_string_values(ctrl, [ref[ctrl, "phoneme"]])[0]
        if not execution.step(1):
            raise RuntimeError(f"libcosim could not step from t = {t} s")
        t += step
        y = observer.last_real_values(face, [ref[face, o] for o in OUTPUTS])
        incisors = observer.last_real_values(face, [ref[face, "incisor_opening"]])[0]
        rows.append({"time": t, "phoneme": phoneme.decode() if isinstance(phoneme, bytes)
                     else phoneme, **{TARGETS[o]: v for o, v in zip(OUTPUTS, targets)},
                     **dict(zip(OUTPUTS, y)), **dict(zip(MUSCLES, acts)),
                     "jaw_opening": opening, "incisor_opening": incisors})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(HERE.parent / "out" / "cosim_libcosim"))
    ap.add_argument("--targets", help="JSON list of targets (default: the identified ones)")
    ap.add_argument("--compare", help="an fmpy run's cosim.csv (default: run it now)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    targets = load_targets(args.targets)
    stop, step = sum(tg["duration"] for tg in targets), 0.005
    build_fmus(out)
    system = (CONTROL / "OspSystemStructure.xml").read_text()
    if args.targets:
        value = escape(str(Path(args.targets).resolve()), {'"': "&quot;"})
        system = system.replace(
            '<Simulator name="control" source="LipMotorControl.fmu"/>',
            '<Simulator name="control" source="LipMotorControl.fmu">\n      <InitialValues>\n'
            f'        <InitialValue variable="targets_file"><String value="{value}"/>'
            '</InitialValue>\n      </InitialValues>\n    </Simulator>')
    (out / "OspSystemStructure.xml").write_text(system)
    t0 = time.perf_counter()
    rows = cosimulate(out, stop, step)
    print("libcosim:")
    missed = report(rows, targets, time.perf_counter() - t0, out / "cosim.csv")
    compare = Path(args.compare) if args.compare else out / "fmpy" / "cosim.csv"
    if not args.compare:
        subprocess.run([sys.executable, str(HERE / "cosim_speech.py"), "--out",
                        str(out / "fmpy")] + (["--targets", args.targets] if args.targets
                                              else []), stdout=subprocess.DEVNULL)
    ref = list(csv.DictReader(open(compare)))
    if len(ref) != len(rows):
        print(f"FAILED: the fmpy run has {len(ref)} steps, libcosim {len(rows)}")
        return 1
    diff = max(abs(float(a[o]) - b[o]) for a, b in zip(ref, rows) for o in OUTPUTS)
    print(f"largest difference from fmpy ({compare}): {diff:.2e} mm over {len(rows)} steps")
    ok = diff <= MATCH and not missed
    print("all targets met, and the masters agree" if ok else
          f"FAILED: a target missed or the masters differ by more than {MATCH} mm")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
