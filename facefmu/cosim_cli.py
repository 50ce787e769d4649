"""`facefmu cosim`: co-simulate a system description once, or a batch of utterances.

    facefmu cosim SYSTEM.xml --targets a.json [b.json ...] [--workers 2] [--out DIR]
    facefmu cosim SYSTEM.xml --stop 0.5 [--set control.tau_fb=0.02] [--record face.lip_width]
    facefmu cosim SYSTEM.xml --targets a.json --grid control.tau_fb=0.02,0.03 --scheduler ADDR

SYSTEM.xml is an OSP system structure (facefmu.cosim.read_system); --fmu NAME=PATH
replaces a simulator's FMU. Each --targets file is one utterance (its duration, the
controller's targets_file parameter), scored against its targets; without targets one
utterance of --stop seconds runs. --grid multiplies the utterances by parameter values.
One utterance runs in this process; several (or --workers, --scheduler) run as a batch on
dask.distributed (facefmu.batch). Writes trajectories and summary (parquet where pyarrow
is installed, else CSV) into --out, prints the tracking table of a single scored
utterance or one line per utterance; exit status 0 when every utterance ran and met its
targets, 1 otherwise.
"""

from pathlib import Path


def add_arguments(parser):
    parser.add_argument("system", metavar="SYSTEM.xml", help="OSP system structure file")
    parser.add_argument("--fmu", action="append", default=[], metavar="NAME=PATH",
                        help="the FMU of simulator NAME (default: the description's)")
    parser.add_argument("--targets", nargs="+", default=[], metavar="FILE",
                        help="speech target files, one utterance each")
    parser.add_argument("--stop", type=float, help="simulated time (s) without --targets")
    parser.add_argument("--step", type=float, help="communication step (s; default: the "
                        "description's BaseStepSize)")
    parser.add_argument("--set", action="append", default=[], metavar="SIM.VAR=VALUE",
                        help="a parameter or start value for every utterance")
    parser.add_argument("--grid", action="append", default=[], metavar="SIM.VAR=V1,V2",
                        help="one utterance per value (axes multiply)")
    parser.add_argument("--record", action="append", default=None,
                        metavar="[COL=]SIM.VAR[@start]", help="what to record (default: "
                        "the speech records with --targets, else every connection)")
    parser.add_argument("--workers", type=int, help="local dask workers (a batch)")
    parser.add_argument("--scheduler", metavar="ADDRESS", help="a dask scheduler to use")
    parser.add_argument("--out", default="out/cosim-batch", help="results folder")
    parser.add_argument("--format", choices=("parquet", "csv"), help="results format")


def _pairs(items, what):
    out = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or "." not in key:
            raise ValueError(f"{what} {item!r} is not SIM.VAR=VALUE")
        out[key] = value
    return out


def run(args):
    from facefmu import speech
    from facefmu.batch import Batch, Utterance, from_targets, grid, run_utterance
    from facefmu.cosim import read_system

    fmus = {k: v for k, v in (f.split("=", 1) for f in args.fmu if "=" in f)}
    if len(fmus) != len(args.fmu):
        raise ValueError("--fmu takes NAME=PATH")
    system = read_system(args.system, fmus)
    if args.step:
        system.step = args.step
    if args.targets:
        utterances = from_targets(args.targets)
    elif args.stop:
        utterances = [Utterance(Path(args.system).stem, args.stop)]
    else:
        raise ValueError("give --targets files or --stop")
    for key, value in _pairs(args.set, "--set").items():
        sim, _, var = key.partition(".")
        for u in utterances:
            u.parameters.setdefault(sim, {})[var] = value
    axes = {k: v.split(",") for k, v in _pairs(args.grid, "--grid").items()}
    if axes:
        utterances = [p for u in utterances for p in grid(u, axes)]
    records = args.record or (speech.records(system) if args.targets else None)
    if len(utterances) == 1 and not (args.workers or args.scheduler):
        from facefmu.batch import BatchResult, _close_masters
        r = run_utterance(system, records, utterances[0])
        _close_masters()
        result = BatchResult([r["summary"]], {utterances[0].name: r["rows"]})
        u = utterances[0]
        if u.targets is not None and r["rows"]:
            print(speech.table(speech.tracking(r["rows"], u.targets)))
    else:
        with Batch(system, records, args.scheduler, args.workers or 2) as batch:
            result = batch.run(utterances)
    bad = 0
    for s in result.summary:
        score = f", {s['met']}/{s['targets']} targets met" if "targets" in s else ""
        state = "ok" if s["ok"] else "FAILED"
        print(f"{s['utterance']}: {state}, {s['wall_s']:.1f} s wall for {s['simulated_s']:g} s "
              f"(real-time factor {s['rtf']:.1f}){score}"
              + (f"; {s['reason']}" if s["reason"] else ""))
        bad += (not s["ok"]) or s.get("met", 0) < s.get("targets", 0)
    paths = result.write(args.out, args.format)
    print("wrote " + " and ".join(str(p) for p in paths))
    print(f"{len(result.summary) - bad} of {len(result.summary)} utterances ran and met "
          "their targets" if args.targets else
          f"{len(result.summary) - bad} of {len(result.summary)} utterances ran")
    return 1 if bad else 0

