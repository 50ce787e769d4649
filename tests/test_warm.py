"""The parallel compilation of the solver's kernels (solver/app/warm.py): its manifest
lists what the default scene calls, its groups keep a function's versions together, and
its processes leave the kernels in the cache for the next process."""

import json
import os
import subprocess
import sys
import textwrap

import pytest

from solver.app import warm

SMALL = ("scatter_matrices", "scatter_vectors")


def _run(code, cache=None):
    env = dict(os.environ)
    if cache is not None:
        env["NUMBA_CACHE_DIR"] = str(cache)
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], env=env,
                         capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_the_manifest_lists_what_the_default_scene_calls():
    used = _run("""
        import json
        from solver.app.warm import exercise, used_kernels
        exercise()
        print(json.dumps([[m, n, args] for (m, n), v in used_kernels().items()
                          for args in v]))
    """)
    data = warm.load_manifest()
    listed = {(e["module"], e["name"], tuple(e["args"])) for e in data["kernels"]}
    called = {(m, n, tuple(a)) for m, n, a in used}
    missing = listed - called
    assert not missing, f"manifest kernels the scene no longer calls: {sorted(missing)}"
    helpers = set(data["helpers"])
    unlisted = {c for c in called - listed if f"{c[0]}.{c[1]}" not in helpers}
    assert not unlisted, ("kernels the scene calls that the manifest does not list "
                          f"(python -m solver.app.warm --record): {sorted(unlisted)}")


def test_argument_types_round_trip_through_their_text():
    from numba.core import types
    for e in warm.load_manifest()["kernels"]:
        for a in e["args"]:
            assert warm.encode(warm.decode(a)) == a
    ro = types.Array(types.float64, 2, "C", readonly=True)
    assert warm.decode(warm.encode(ro)) == ro
    assert warm.decode("omitted:1.0") == types.Omitted(1.0)
    with pytest.raises(ValueError, match="literal"):
        warm.encode(types.literal(4))
    with pytest.raises(ValueError, match="unknown numba type"):
        warm.decode("float65")


def test_groups_balance_time_and_keep_a_functions_versions_together():
    entries = [{"module": "m", "name": "a", "args": ["int64"], "seconds": 5.0},
               {"module": "m", "name": "a", "args": ["float64"], "seconds": 5.0},
               {"module": "m", "name": "b", "args": [], "seconds": 6.0},
               {"module": "m", "name": "c", "args": [], "seconds": 3.0},
               {"module": "m", "name": "d", "args": [], "seconds": 1.0}]
    parts = warm.groups(entries, 2)
    assert len(parts) == 2
    owner = {}
    for i, part in enumerate(parts):
        for e in part:
            assert owner.setdefault(e["name"], i) == i
    loads = sorted(sum(e["seconds"] for e in p) for p in parts)
    assert loads == [10.0, 10.0]
    assert warm.groups(entries, 8) and len(warm.groups(entries, 8)) == 4
    assert sum(len(p) for p in warm.groups(entries, 1)) == len(entries)


def test_two_processes_leave_the_kernels_in_the_cache(tmp_path):
    small = {"kernels": [e for e in warm.load_manifest()["kernels"] if e["name"] in SMALL]}
    assert len(small["kernels"]) == 2
    (tmp_path / "m.json").write_text(json.dumps(small))
    res = _run(f"""
        import json
        from solver.app.warm import warm_kernels
        m = json.load(open({str(tmp_path / "m.json")!r}))
        print(json.dumps(warm_kernels(jobs=2, manifest=m)))
    """, cache=tmp_path / "cache")
    assert res["jobs"] == 2 and not res["warm"]
    after = _run(f"""
        import json
        from solver.core.numba_config import configure_numba
        configure_numba()
        from numba.core import event
        compiled = []
        class L(event.Listener):
            def on_start(self, ev): compiled.append(ev.data["dispatcher"].py_func.__name__)
            def on_end(self, ev): pass
        event.register("numba:compile", L())
        from solver.app.warm import _dispatcher, decode
        m = json.load(open({str(tmp_path / "m.json")!r}))
        hits = 0
        for e in m["kernels"]:
            d = _dispatcher(e["module"], e["name"])
            d.compile(tuple(decode(a) for a in e["args"]))
            hits += sum(d.stats.cache_hits.values())
        print(json.dumps({{"compiled": compiled, "hits": hits}}))
    """, cache=tmp_path / "cache")
    assert after["compiled"] == [] and after["hits"] == 2


def test_a_stale_manifest_is_reported_and_not_fatal(tmp_path):
    stale = {"kernels": [{"module": "solver.core.kernels.scatter", "name": "no_such_kernel",
                          "args": ["float64"], "seconds": 1.0}]}
    (tmp_path / "m.json").write_text(json.dumps(stale))
    res = _run(f"""
        import json
        from solver.app.warm import warm_kernels
        lines = []
        m = json.load(open({str(tmp_path / "m.json")!r}))
        res = warm_kernels(jobs=1, manifest=m, log=lines.append)
        print(json.dumps(dict(res, lines=lines)))
    """, cache=tmp_path / "cache")
    assert "no_such_kernel" in res["error"]
    assert "compile at their first calls" in res["lines"][-1]
