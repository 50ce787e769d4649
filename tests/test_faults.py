"""Faults give clear errors, never a crash, and lose nothing: corrupted scene and mesh
files, a missing data folder, an unwritable numba cache directory, and through the FMU
(fmpy, in a fresh process) reset, re-instantiation, freeInstance in the middle of a run
and unusable parameters.

Tests that corrupt the reference face's files work on copies of a few of its lines in
tmp_path (and skip where ../shared/data/reference-face is absent); the others corrupt
small hand-written files.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from solver.face.anatomy.ansys import _read_elements, _read_nodes, load_ansys_face
from solver.core.errors import FaceFMUError, MeshError, MeshFileError
from solver.app.scene import Scene, SceneError, load_scene
from solver.app.simulation import BUILTIN_DIR, Simulation
from solver.face.anatomy.reference import reference_face_dir
from conftest import needs_reference_face
from conftest import SCRIPTS

DATA = reference_face_dir()
needs_data = needs_reference_face


# ------------------------------------------------------------------------ scene files

BAD_SCENES = {
    "truncated": '[scene]\nname = "x"\nanalysis = "trans',
    "unclosed table": '[scene]\nanalysis = "transient"\n[muscles\ndriven = ["OOP"]\n',
    "nan duration": "[scene]\nduration = nan\n",
    "inf interval": "[outputs]\ninterval = inf\n",
    "number for a flag": "[effects]\nlip_contact = 1\n",
    "negative force scale": "[muscles]\nforce_scale = { OOP = -1.0 }\n",
    "section not a table": "scene = 3\n",
    "schedule not an array": "schedule = 3\n",
    "times not a list": '[[schedule]]\nmuscle = "OOP"\nkind = "pwl"\ntimes = 3\nvalues = [0.0]\n',
    "control character": '[scene]\nname = "a\x01b"\n',
    "duplicate key": '[scene]\nname = "a"\nname = "b"\n',
}


@pytest.mark.parametrize("label", list(BAD_SCENES))
def test_corrupted_scene_files_are_refused_naming_the_file(tmp_path, label):
    path = tmp_path / "bad.toml"
    path.write_text(BAD_SCENES[label])
    with pytest.raises(SceneError, match=str(path)):
        load_scene(path)
    with pytest.raises(SceneError, match=str(path)):       # and before any model is built
        Simulation(str(path))


def test_a_directory_given_as_scene_file_is_refused(tmp_path):
    with pytest.raises(SceneError, match="cannot read"):
        load_scene(tmp_path)


def test_a_scene_file_that_is_not_text_is_refused_naming_the_file(tmp_path):
    path = tmp_path / "binary.toml"
    path.write_bytes(b'[scene]\nname = "\xff\xfe"\n' + bytes(range(128, 256)))
    with pytest.raises(SceneError, match=str(path)):
        load_scene(path)


ROUNDING = (BUILTIN_DIR / "rounding_u.toml").read_text()
EDITS = st.lists(st.tuples(st.integers(0, len(ROUNDING) - 1),
                           st.sampled_from(["delete", "insert", "replace"]),
                           st.sampled_from(list(' \n"=[]{},.#-+0123456789abcdefnitrue'))),
                 min_size=1, max_size=6)


@settings(max_examples=150, deadline=None)
@given(EDITS)
def test_randomly_edited_scene_files_load_or_give_a_scene_error(tmp_path_factory, edits):
    text = list(ROUNDING)
    for pos, kind, ch in edits:
        pos = min(pos, len(text) - 1)
        if kind == "delete":
            del text[pos]
        elif kind == "insert":
            text.insert(pos, ch)
        else:
            text[pos] = ch
    path = tmp_path_factory.mktemp("fuzz") / "scene.toml"
    path.write_text("".join(text))
    try:
        scene = load_scene(path)
    except SceneError as exc:
        assert str(path) in str(exc)
    else:
        assert isinstance(scene, Scene)


# ------------------------------------------------------------------------- mesh files

def node_line(i, x, y, z):
    return f"{i:8d}{x:20.12E}{y:20.12E}{z:20.12E}\n"


def elem_line(ids, eid, mat=1):
    return "".join(f"{v:6d}" for v in [*ids, mat, 1, 1, 1, 0, eid]) + "\n"


CUBE = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)]


def tiny_face(folder, nodes=None, elems=None, skull=None):
    """A hand-written one-brick ANSYS face folder (no lip files: a complete read stops at
    upperlip_filled.smesh)."""
    folder.mkdir(exist_ok=True)
    (folder / "newface.node").write_text(nodes if nodes is not None else
                                         "".join(node_line(i + 1, *p) for i, p in enumerate(CUBE)))
    (folder / "newface.elem").write_text(elems if elems is not None else
                                         elem_line(range(1, 9), 1))
    (folder / "fixed_skull_nose.node").write_text(
        skull if skull is not None else "".join(node_line(i + 1, *CUBE[i]) for i in range(2)))
    (folder / "fixed_mandible.node").write_text(node_line(3, *CUBE[2]))
    return folder


def test_tiny_hand_written_face_reads_up_to_the_first_missing_file(tmp_path):
    with pytest.raises(MeshFileError, match=r"upperlip_filled\.smesh: required file is missing"):
        load_ansys_face(tiny_face(tmp_path / "face"))


def _cube_nodes(edit=None):
    lines = [node_line(i + 1, *p) for i, p in enumerate(CUBE)]
    return "".join(edit(lines) if edit else lines)


TINY_FAULTS = {
    "letter in y": (dict(nodes=_cube_nodes(lambda ls: ls[:2] + [ls[2][:30] + "x" + ls[2][31:]]
                                           + ls[3:])), r"newface\.node:3: cannot read y"),
    "nan coordinate": (dict(nodes=_cube_nodes(lambda ls: ls[:4] + [f"{5:8d}{'nan':>20}"
                                                                   f"{0.0:20.12E}{1.0:20.12E}\n"]
                                              + ls[5:])), r"newface\.node:5: non-finite"),
    "duplicate node id": (dict(nodes=_cube_nodes(lambda ls: ls + [ls[3]])),
                          r"newface\.node:9: node id 4 is defined twice"),
    "line cut short": (dict(nodes=_cube_nodes(lambda ls: ls[:7] + [ls[7][:40] + "\n"])),
                       r"newface\.node:8: expected 4 or 7 fixed-width fields, found 3"),
    "empty node file": (dict(nodes=""), r"newface\.node: no nodes"),
    "binary element file": (dict(elems="\x00\xff\x17garbage\x80\n"), r"newface\.elem:1"),
    "element with 12 fields": (dict(elems=elem_line(range(1, 9), 1)[:72] + "\n"),
                               r"newface\.elem:1: expected 14 .*found 12"),
    "element on a missing node": (dict(elems=elem_line([1, 2, 3, 4, 5, 6, 7, 99], 1)),
                                  r"newface\.elem:1: element 1 refers to node 99"),
    "fixed node moved": (dict(skull=node_line(1, 0.0, 0.0, 0.5)),
                         r"fixed_skull_nose\.node:1: node 1 is 0\.5 mm away"),
}


@pytest.mark.parametrize("label", list(TINY_FAULTS))
def test_broken_hand_written_files_name_file_and_line(tmp_path, label):
    kw, message = TINY_FAULTS[label]
    with pytest.raises(MeshFileError, match=message):
        load_ansys_face(tiny_face(tmp_path / "face", **kw))


def test_a_flat_brick_is_refused_naming_it(tmp_path):
    flat = "".join(node_line(i + 1, x, y, 0.0) for i, (x, y, z) in enumerate(CUBE))
    with pytest.raises(MeshError, match="brick 1 is of zero volume"):
        load_ansys_face(tiny_face(tmp_path / "face", nodes=flat))


def _few_lines(name, count):
    return "".join((DATA / name).read_text(encoding="latin-1").splitlines(keepends=True)[:count])


@needs_data
@pytest.mark.parametrize("name, reader", [("newface.node", _read_nodes),
                                          ("newface.elem", _read_elements)])
def test_corrupted_copies_of_reference_lines_give_mesh_file_errors(tmp_path, name, reader):
    """A few lines of the reference files, then random byte corruptions of them: each
    read either succeeds (a harmless change) or raises MeshFileError naming the file."""
    text = _few_lines(name, 40).encode("latin-1")
    good = tmp_path / name
    good.write_bytes(text)
    reader(good)                                           # the copied lines read
    rng = np.random.default_rng(9)
    outcomes = {"read": 0, "refused": 0}
    for k in range(60):
        data = bytearray(text)
        for pos in rng.integers(0, len(data), rng.integers(1, 4)):
            data[pos] = int(rng.integers(0, 256))
        bad = tmp_path / f"{k}" / name
        bad.parent.mkdir()
        bad.write_bytes(bytes(data))
        try:
            reader(bad)
            outcomes["read"] += 1
        except MeshFileError as exc:
            assert exc.path == str(bad)
            outcomes["refused"] += 1
    assert outcomes["refused"] > 10, outcomes


@needs_data
def test_a_truncated_reference_node_file_names_the_element_that_lost_its_node(tmp_path):
    face = tmp_path / "face"
    face.mkdir()
    for f in DATA.iterdir():
        (face / f.name).symlink_to(f)
    (face / "newface.node").unlink()
    (face / "newface.node").write_text(_few_lines("newface.node", 200))
    with pytest.raises(MeshFileError, match=r"newface\.elem:\d+: element \d+ refers to node"):
        Simulation("default", anatomy=str(face))


# ------------------------------------------------------------------ missing data folder

def test_a_missing_anatomy_folder_is_named(tmp_path):
    with pytest.raises(FaceFMUError, match="nowhere"):
        Simulation("default", anatomy=str(tmp_path / "nowhere"))


def test_an_empty_anatomy_folder_names_the_first_missing_file(tmp_path):
    with pytest.raises(MeshFileError, match=r"newface\.node: required file is missing"):
        Simulation("default", anatomy=str(tmp_path))


@needs_data
def test_a_folder_without_its_lip_surfaces_names_the_file(tmp_path):
    face = tmp_path / "face"
    face.mkdir()
    for f in DATA.iterdir():
        if f.name != "lowerlip_filled.smesh":
            (face / f.name).symlink_to(f)
    with pytest.raises(MeshFileError, match=r"lowerlip_filled\.smesh: required file is missing"):
        load_ansys_face(face)


STALE_CHECK = """
import json
import numpy as np
import solver.core.kernels.material_point as mp
W = mp.response(np.diag([1.1, 0.95, 0.97]), [2.5e-3, 0.0, 1.175e-3, 0.0, 0.0, 0.8])[0]
print(json.dumps({"file": mp.__file__, "W": W,
                  "hits": sum(mp.point_response.stats.cache_hits.values()),
                  "misses": sum(mp.point_response.stats.cache_misses.values())}))
"""


def test_an_edited_helper_in_another_file_recompiles_the_cached_kernels_that_call_it(
        tmp_path):
    """A copy of the solver package, run in fresh processes with their own cache folders:
    the cached kernel material_point.point_response has the jitted helper vol_energy of
    mooney_rivlin.py compiled into it. A second run loads it from the cache (same energy);
    after vol_energy's U is doubled in the copy, a third run recompiles and gives the new
    energy (a stamp of the kernel's own file would have loaded the stale kernel)."""
    import shutil
    from conftest import ROOT
    copy = tmp_path / "copy"
    shutil.copytree(ROOT / "solver", copy / "solver",
                    ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    base = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CACHE_DIR",
                                                             "FACEFMU_CACHE_DIR")}
    env = {**base, "PYTHONPATH": str(copy), "NUMBA_CACHE_DIR": str(tmp_path / "numba"),
           "FACEFMU_CACHE_DIR": str(tmp_path / "facefmu")}

    def run():
        out = subprocess.run([sys.executable, "-c", STALE_CHECK], env=env, cwd=tmp_path,
                             capture_output=True, text=True, timeout=600)
        assert out.returncode == 0, out.stderr[-3000:]
        return json.loads(out.stdout.strip().splitlines()[-1])

    cold, warm = run(), run()
    assert cold["file"].startswith(str(copy))
    assert (cold["misses"], warm["hits"], warm["misses"]) == (1, 1, 0)   # cached, then used
    assert warm["W"] == cold["W"]
    helper = copy / "solver" / "core" / "kernels" / "mooney_rivlin.py"
    old = "return (J - 1.0) ** 2 / d, "
    assert old in helper.read_text()
    helper.write_text(helper.read_text().replace(old, "return 2.0 * (J - 1.0) ** 2 / d, "))
    edited = run()
    J = 1.1 * 0.95 * 0.97
    assert edited["misses"] == 1 and edited["hits"] == 0
    assert edited["W"] == pytest.approx(cold["W"] + (J - 1.0) ** 2 / 0.8, rel=1e-12)


# ----------------------------------------------------------------- numba cache directory

CACHE_CHECK = """
import json, sys, warnings
import numpy as np
if sys.argv[1] == "no-temp":            # no temporary folder can be written either
    import tempfile
    def refuse(*args, **kw):
        raise PermissionError(13, "read-only file system")
    tempfile.mkdtemp = refuse
    tempfile.gettempdir = lambda: sys.argv[2]
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    import solver
    from solver.core import _cache
    from solver.core.kernels.invariants import inverse3
    det = inverse3(np.diag([2.0, 3.0, 4.0]), np.empty((3, 3)))
print(json.dumps({"cache_dir": None if _cache.CACHE_DIR is None else str(_cache.CACHE_DIR),
                  "det": det, "hits": sum(inverse3.stats.cache_hits.values()),
                  "warnings": [str(w.message) for w in caught
                               if issubclass(w.category, RuntimeWarning)]}))
"""


def _cache_run(tmp_path, env, mode="normal", blocked=""):
    base = {k: v for k, v in os.environ.items()
            if k not in ("NUMBA_CACHE_DIR", "FACEFMU_CACHE_DIR", "XDG_CACHE_HOME", "TMPDIR")}
    run = subprocess.run([sys.executable, "-c", CACHE_CHECK, mode, blocked],
                         env={**base, "TMPDIR": str(tmp_path / "tmp"), **env},
                         capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


@pytest.fixture
def blocked(tmp_path):
    """A path that no one can create a directory under (it goes through a file)."""
    (tmp_path / "tmp").mkdir()
    f = tmp_path / "a-file"
    f.write_text("")
    return f / "cache"


def test_an_unwritable_numba_cache_dir_falls_back_to_a_private_reused_folder(tmp_path, blocked):
    first = _cache_run(tmp_path, {"NUMBA_CACHE_DIR": str(blocked)})
    assert first["det"] == 24.0
    assert any(str(blocked) in w and "not writable" in w for w in first["warnings"])
    fallback = Path(first["cache_dir"])
    assert fallback.parent == tmp_path / "tmp" and fallback.name.startswith("facefmu-numba-")
    assert oct(fallback.stat().st_mode & 0o777) == oct(0o700)
    assert list(fallback.rglob("*.nbi"))                     # the kernel was cached there
    second = _cache_run(tmp_path, {"NUMBA_CACHE_DIR": str(blocked)})
    assert second["cache_dir"] == first["cache_dir"] and second["hits"] >= 1   # reused


def test_a_home_without_a_writable_cache_falls_back(tmp_path, blocked):
    res = _cache_run(tmp_path, {"HOME": str(blocked)})
    assert res["det"] == 24.0 and res["cache_dir"].startswith(str(tmp_path / "tmp"))
    assert any("not writable" in w for w in res["warnings"])


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0,
                    reason="root writes into read-only directories")
def test_a_read_only_numba_cache_dir_falls_back(tmp_path):
    (tmp_path / "tmp").mkdir()
    ro = tmp_path / "ro"
    ro.mkdir(mode=0o555)
    try:
        res = _cache_run(tmp_path, {"NUMBA_CACHE_DIR": str(ro)})
    finally:
        ro.chmod(0o755)
    assert res["det"] == 24.0 and res["cache_dir"] != str(ro)


def test_with_no_writable_folder_at_all_kernels_still_compile(tmp_path, blocked):
    res = _cache_run(tmp_path, {"NUMBA_CACHE_DIR": str(blocked)}, "no-temp", str(blocked))
    assert res["det"] == 24.0 and res["cache_dir"] is None
    assert any("compile at every start" in w for w in res["warnings"])


def test_a_shared_fallback_folder_someone_else_could_write_is_not_used(tmp_path, monkeypatch):
    import tempfile
    from solver.core import _cache
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    mine = _cache._fallback_dir()
    assert mine.parent == tmp_path and oct(mine.stat().st_mode & 0o777) == oct(0o700)
    assert _cache._fallback_dir() == mine                   # reused
    mine.chmod(0o777)                                       # now anyone could plant kernels
    other = _cache._fallback_dir()
    assert other != mine and other.parent == tmp_path
    mine.chmod(0o700)


# ---------------------------------------------------------------------- through the FMU

def test_fmu_reset_reinstantiation_free_instance_and_bad_parameters(fmu, tmp_path):
    bad_scene = tmp_path / "bad.toml"
    bad_scene.write_text(BAD_SCENES["unclosed table"])
    bad_face = tiny_face(tmp_path / "face", nodes=TINY_FAULTS["letter in y"][0]["nodes"])
    out = tmp_path / "out.json"
    run = subprocess.run([sys.executable, str(SCRIPTS / "fault_lifecycle.py"), str(fmu),
                          str(out), str(bad_scene), str(tmp_path / "nowhere"), str(bad_face)],
                         capture_output=True, text=True, timeout=600, cwd=tmp_path)
    assert "ok" in run.stdout.splitlines() and out.is_file(), \
        run.stdout[-2000:] + run.stderr[-4000:]                # no crash on the way
    res = json.loads(out.read_text())
    ref = res["ref3"]
    assert ref != res["rest"]                                  # the steps moved the lips
    assert res["reinstantiated3"] == ref                       # a new instance: the same run
    assert res["oop_after_reset"] == 0.0 and res["rest_after_reset"] == res["rest"]
    assert res["after_reset3"] == ref and res["after_terminate_reset3"] == ref
    assert res["beside_freed3"] == ref                         # freeing one disturbs no other
    assert res["nan_status"] == 2
    statuses = res["bad_parameters"]
    assert set(statuses) == {str(bad_scene), str(tmp_path / "nowhere"), str(bad_face)}
    assert all(s >= 3 for s in statuses.values()), statuses   # fmi2Error or fmi2Fatal
    for needle in (f"{bad_scene}: [] not valid TOML", f"{tmp_path / 'nowhere'} does not exist",
                   "newface.node:3: cannot read y"):
        assert needle in run.stdout, needle                    # each logged, named
    assert res["then3"] == ref                                 # and a new instance works
    assert run.returncode == 0, run.stderr[-3000:]             # the process exits cleanly


def test_the_kernel_cache_stamp_covers_every_kernel_file(tmp_path):
    """numba's cached kernels are keyed by the content of every solver file with numba
    functions, so that an edit of a jitted helper in another file recompiles its callers;
    files without numba functions do not take part."""
    import shutil
    from solver.core._cache import kernel_sources_stamp
    from conftest import ROOT
    root = tmp_path / "solver"
    assert kernel_sources_stamp() == kernel_sources_stamp(ROOT / "solver")  # the package,
    shutil.copytree(ROOT / "solver" / "core" / "kernels", root / "kernels")  # rom's too
    shutil.copy(ROOT / "solver" / "app" / "fidelity.py", root / "fidelity.py")
    first = kernel_sources_stamp(root)
    assert kernel_sources_stamp(root) == first and len(first) == 64
    again = tmp_path / "again"
    shutil.copytree(root, again)
    (again / "fidelity.py").write_text((again / "fidelity.py").read_text() + "\n# edit\n")
    assert kernel_sources_stamp(again) == first          # not a kernel file
    edited = tmp_path / "edited"
    shutil.copytree(root, edited)
    helper = edited / "kernels" / "invariants.py"
    helper.write_text(helper.read_text() + "\n# edit\n")
    assert kernel_sources_stamp(edited) != first
