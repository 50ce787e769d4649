"""Trained reduced models on disk: one .npz per model, cached per user.

A model is valid for one full-order model: the anatomy, mesh level, half face, brick
rows and the scene's effects (driven muscles, force scales, stiffening and its rule,
contact, inertia and damping constants, density, formulation, gravity). Those make the
key (`model_key`); its hash names the file, and the key itself is stored in the file and
checked on loading, so a model is never used for another face or another set of effects
(nor after the full-order physics changed: PHYSICS).

Cache folder: <user cache>/rom (solver.core._cache.user_cache_dir: $FACEFMU_CACHE_DIR, else
$XDG_CACHE_HOME/facefmu, else ~/.cache/facefmu), or $FACEFMU_ROM_DIR. Shipped models:
solver/rom/models (SHIPPED), the default scene's, made by `python benchmarks/rom_train.py
--ship` (their meta records the command and the commit); looked up after the user cache,
so that a model the user trained for the same key wins. stale_models() lists the shipped
files whose key no built-in scene has any more (tests/test_rom_shipped.py). Files are plain
numpy .npz (no pickles) that can be copied and shipped; `load_model(path)` reads one
from anywhere.

Arrays in a file: V (3 n, r) the basis (zero rows on constrained DOFs), bricks (k,) and
weights (k,) the cubature, M_r, K0_r (r, r) the reduced mass and rest passive stiffness,
sigma the POD singular values, trust_threshold (1,), and meta: a JSON string (the key,
basis size, captured energy, ECSW tolerance and residual, training runs and times,
calibration figures).
"""

import functools
import hashlib
import json
import os
from pathlib import Path

import numpy as np

from solver.core._cache import user_cache_dir
from solver.core.errors import FaceFMUError
from solver.face.terms.contact import PENALTY

# The file's layout and what a model holds: 2: u = V q + L(jaw pose) (solver.rom.lifting),
# snapshots with the jaw moving and meta "jaw_envelope".
FORMAT = 2
# The full-order physics a model's snapshots came from: bumped when a term's forces change
# (the key then differs, so older models and cached snapshot runs are not used).
# 2: lip contact faded beyond the edge of a slave's candidate triangles;
# 3: the generic face's teeth one surface past the free inner surface;
# 4: the teeth's penalty faded beyond their free edges, not released;
# 5: the teeth's rest offsets, the lips' faded penalty with exact derivatives over the
#    master's nodes, 24 candidate triangles per lip slave.
PHYSICS = 5
ARRAYS = ("V", "bricks", "weights", "M_r", "K0_r", "sigma", "trust_threshold")
SHIPPED = Path(__file__).resolve().parent / "models"


class ModelNotTrained(FaceFMUError, LookupError):
    """No trained reduced model for a scene; names the training command."""


@functools.cache
def generic_geometry(level, half, rows):
    """A fingerprint (str, 16 hex digits) of the generic face built from code: the
    sha256 of its nodes (rounded to 1e-4 mm), bricks, node sets, fibres, contact and rigid
    surfaces. The generic face has no file whose path could name it in a model's key, so
    a change of its shape in code must change the key (and make a shipped model stale)."""
    from solver.face.anatomy.load import load_anatomy
    a = load_anatomy("generic", level, half, rows=rows)
    h = hashlib.sha256()

    def add(x):
        h.update(np.ascontiguousarray(x).tobytes())
    add(np.round(a.mesh.nodes, 4))
    add(a.mesh.bricks)
    for name in sorted(a.mesh.node_sets):
        h.update(name.encode())
        add(a.mesh.node_sets[name])
    for f in a.fibres:
        h.update(f"{f.muscle}{f.side}{f.n_cables}".encode())
        add(np.round(f.points, 4))
    for name in sorted(a.contact_surfaces):
        h.update(name.encode())
        add(a.contact_surfaces[name])
    for name in sorted(a.rigid_surfaces):
        h.update(name.encode())
        add(np.round(a.rigid_surfaces[name].vertices, 4))
        add(a.rigid_surfaces[name].triangles)
    return h.hexdigest()[:16]


def model_key(scene):
    """The fields of a solver.app.scene.Scene that a reduced model depends on (a dict)."""
    anatomy = scene.anatomy
    rows = scene.rows
    geometry = {}
    if anatomy != "generic":
        anatomy = str(Path(anatomy).resolve())
    else:                             # a level's own rows, given or not, are one model
        from solver.face.anatomy.generic import LEVELS
        if rows == LEVELS[scene.level][1]:
            rows = None
        geometry = {"geometry": generic_geometry(scene.level, bool(scene.half), rows)}
    return {"format": FORMAT, "physics": PHYSICS, "anatomy": anatomy, **geometry,
            "level": scene.level if
            scene.anatomy == "generic" else "-", "half": bool(scene.half),
            "rows": rows, "driven": list(scene.driven),
            "force_scale": {m: float(v) for m, v in sorted(scene.force_scale.items())
                            if v != 1.0},
            "stiffening": bool(scene.stiffening), "stiffening_rule": scene.stiffening_rule,
            "muscles": scene.muscle_constants(),
            "lip_contact": bool(scene.lip_contact), "teeth_contact": bool(scene.teeth_contact),
            "inertia": bool(scene.inertia), "damping": bool(scene.damping),
            "alpha": float(scene.alpha), "beta": float(scene.beta),
            "density": float(scene.density), "formulation": scene.formulation,
            "gravity": scene.gravity,
            # only where not the default: a model at the default penalty keeps the key it
            # has without this entry
            **({"lip_penalty": float(scene.lip_penalty)} if scene.lip_penalty != PENALTY
               else {})}


def key_hash(key):
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:12]


def cache_dir():
    return Path(os.environ.get("FACEFMU_ROM_DIR") or user_cache_dir() / "rom")


def file_name(key):
    """The file name of the model of a key (model_key)."""
    name = Path(key["anatomy"]).name if key["anatomy"] != "generic" else "generic"
    half = "half" if key["half"] else "full"
    return f"rom-{name}-{key['level']}-{half}-{key_hash(key)}.npz"


def model_path(scene, folder=None):
    return Path(folder or cache_dir()) / file_name(model_key(scene))


def save_model(path, arrays, meta):
    """Write a model (arrays: dict of ARRAYS; meta: JSON-able dict) to path (.npz)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, meta=np.array(json.dumps(meta, sort_keys=True)),
                        **{k: np.asarray(arrays[k]) for k in ARRAYS})
    os.replace(tmp, path)
    return path


def load_model(path, key=None):
    """(arrays dict, meta dict) from a .npz; with key, FaceFMUError unless it matches."""
    with np.load(Path(path), allow_pickle=False) as f:
        meta = json.loads(str(f["meta"]))
        arrays = {k: f[k] for k in ARRAYS}
    if meta.get("key", {}).get("format") != FORMAT:
        raise FaceFMUError(f"{path}: reduced model of another format; retrain it")
    if key is not None and meta["key"] != json.loads(json.dumps(key)):
        diff = sorted(k for k in key if meta["key"].get(k) != key[k])
        raise FaceFMUError(f"{path}: reduced model trained for other settings ({diff})")
    return arrays, meta


TRAIN_COMMAND = "python benchmarks/rom_train.py --scene SCENE"


def find_model(scene, folders=()):
    """(arrays, meta) of the model of scene: the first of model_path(scene, folder) that
    exists over folders (a path or a sequence of paths), the user cache and SHIPPED; else
    ModelNotTrained naming the training command."""
    folders = [folders] if isinstance(folders, (str, Path)) else list(folders or ())
    paths = [model_path(scene, f) for f in folders] + [model_path(scene),
                                                       model_path(scene, SHIPPED)]
    for path in paths:
        if path.is_file():
            return load_model(path, model_key(scene))
    k = model_key(scene)
    where = ", ".join(str(p.parent) for p in paths)
    from solver.app.simulation import builtin_scenes
    name = scene.name if scene.name in builtin_scenes() else "SCENE"
    raise ModelNotTrained(
        f"no trained realtime model for scene {scene.name!r} (anatomy {k['anatomy']}, "
        f"level {k['level']}, half {k['half']}, muscles {','.join(k['driven'])}, lip "
        f"contact {k['lip_contact']}, teeth contact {k['teeth_contact']}; looked for "
        f"{paths[-1].name} in {where}); train it with: "
        f"{TRAIN_COMMAND.replace('SCENE', name)}"
        + (" (SCENE: this scene's TOML file)" if name == "SCENE" else "")
        + ". An FMU carries models packed by "
        "python build_fmu.py --rom FILE.npz (or --with-realtime for the speech scene)")


def shipped_scenes():
    """The built-in scenes whose realtime model ships (SHIPPED): default (and every
    built-in scene of the same key, e.g. speech)."""
    return ("default",)


def stale_models(folder=SHIPPED):
    """The model files in folder whose stored key is not the current key of the scene
    they name (meta "scene", at the realtime knobs), or that fail to load: [(file name,
    reason)]. Empty when every model matches the current physics."""
    from solver.app.fidelity import apply_fidelity
    from solver.app.simulation import resolve_scene
    out = []
    for path in sorted(Path(folder).glob("*.npz")):
        try:
            with np.load(path, allow_pickle=False) as f:
                meta = json.loads(str(f["meta"]))
            key = model_key(apply_fidelity(resolve_scene(meta["scene"]), "realtime"))
        except Exception as exc:                        # reported, not raised
            out.append((path.name, f"{type(exc).__name__}: {exc}"))
            continue
        if meta.get("key") != json.loads(json.dumps(key)):
            diff = sorted(k for k in key if meta.get("key", {}).get(k) != key[k])
            out.append((path.name, f"trained for other settings: {diff}"))
        elif path.name != file_name(key):
            out.append((path.name, f"named {path.name}, its key's name is {file_name(key)}"))
    return out
