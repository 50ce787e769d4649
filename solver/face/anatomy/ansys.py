"""Reader of the published ANSYS reference face (Nazari, Perrier, Chabanas, Payan).

    anatomy = load_ansys_face("path/to/reference-face")

reads a folder of ANSYS exports and returns an `Anatomy` (name 'reference', both sides,
half=False). Your own ANSYS face loads the same way if it is written with the same file
names and formats. Units: mm. Axes: x medial-lateral (x = 0 mid-sagittal, the subject's
left at x < 0), y posterior-anterior, z inferior-superior.

Files. Required: newface.node, newface.elem (the mesh: ANSYS NWRITE nodes, EWRITE 8-node
bricks, a wedge being a brick with repeated ids), fixed_skull_nose.node, fixed_mandible.node
(the held nodes), muscles.node, muscles.elem (the LINK10 cables; a right node's id is its
left mirror's + 20000), face_muscles_topology.mac (the APDL macro naming each left
fibre's nodes), upperlip_filled.smesh, lowerlip_filled.smesh (closed lip surfaces, facets
by node id). Optional, left out when absent: maxilla_lipcontact.obj,
mandible_lipcontact.obj (rigid teeth), OOP_active_elements.elem, OOM_active_elements.elem,
OOP_elements.txt (the paper's OOP region).

The anatomy: mesh.node_ids, mesh.element_ids are the file ids, mesh.bricks 0-based
indices; node_sets 'fixed_skull', 'fixed_mandible', 'fixed' (their union), 'midsagittal'
(|x| < 0.1 mm); element_sets 'mat_<k>' per MAT number and 'OOP_active', 'OOM_active',
'OOP_region' where their files exist (no 'layer_*' sets: the reference mesh has no
reliable layering). Bricks are used in ANSYS's I..P order; a mesh whose bricks are all
inverted (a mirror image) is reordered, a mix is refused by `Mesh`.

Muscles: the macro's labels are MUSCLE_NAMES (MAS, the masseter, is skipped); each macro
fibre is a left Fibre, its mirror (node id + 20000) the right one. The fibres are the
macro's, not the chains of muscles.elem (OOP: 14 cables a side, as in the paper's Table 3).
Insertions (Fibre.insertion) are the cable points within 0.5 mm of a fixed node and, at a
bone end of a fibre (nearer to a fixed node than to a lip contact node), the run of
consecutive points outside the soft-tissue mesh (farther than 0.05 mm from every brick)
that starts there. Landmarks (node indices), on the lip contact surfaces:
upper/lower_lip_edge the lowest/highest mid-sagittal node of the upper/lower lip surface,
upper/lower_lip_front their most anterior mid-sagittal nodes, corner_left/corner_right
the upper-lip nodes within 0.5 mm of a lower-lip node with the smallest/largest x.

File formats, sets, the muscle mapping, insertions and landmarks in full: docs/method.md,
section 'The reference face: the ANSYS files'.
"""

import re
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from solver.core.element import shape_functions, shape_gradients
from solver.core.errors import FaceFMUError, MeshError, MeshFileError
from solver.core.mesh import BRICK_FACES, Mesh
from solver.face.anatomy.base import MUSCLE_NAMES, Anatomy, Fibre, RigidSurface

NODE_FILE, ELEM_FILE = "newface.node", "newface.elem"
FIXED_FILES = {"fixed_skull": "fixed_skull_nose.node", "fixed_mandible": "fixed_mandible.node"}
MUSCLE_NODE_FILE, MUSCLE_ELEM_FILE = "muscles.node", "muscles.elem"
MACRO_FILE = "face_muscles_topology.mac"
LIP_FILES = {"upper_lip": "upperlip_filled.smesh", "lower_lip": "lowerlip_filled.smesh"}
TEETH_FILES = {"upper_teeth": "maxilla_lipcontact.obj", "lower_teeth": "mandible_lipcontact.obj"}
ACTIVE_FILES = {"OOP_active": "OOP_active_elements.elem", "OOM_active": "OOM_active_elements.elem"}
REGION_FILE = "OOP_elements.txt"     # the paper's OOP region (Table 4's strains)

RIGHT_ID_OFFSET = 20000     # right cable node id = left id + 20000
MIDLINE_TOL = 0.1           # mm, |x| below which a node is mid-sagittal
MIRROR_TOL = 0.01           # mm, left/right cable node mismatch allowed
FIXED_MATCH_TOL = 1e-3      # mm, fixed-node file coordinates against newface.node
INSERTION_TOL = 0.5         # mm, a cable point this close to a fixed node is attached
OUTSIDE_TOL = 0.05          # mm, a cable point farther from every brick is outside
CORNER_GAP = 0.5            # mm, upper-lip nodes this close to the lower lip join it

NODE_SPANS = [(0, 8), (8, 28), (28, 48), (48, 68)]
NODE_FIELD_COUNTS = (4, 7)  # id, x, y, z (+ 3 rotation angles NWRITE may append)
ELEM_SPANS = [(6 * i, 6 * i + 6) for i in range(14)]
ELEM_FIELDS = ("I", "J", "K", "L", "M", "N", "O", "P", "MAT", "TYPE", "REAL", "SECNUM",
               "ESYS", "element id")
MIRROR_ORDER = [0, 3, 2, 1, 4, 7, 6, 5]     # J <-> L, N <-> P: reverses a brick


def load_ansys_face(folder):
    """Read an ANSYS face folder (see the module docstring) into an Anatomy."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FaceFMUError(f"ANSYS face folder not found: {folder}")
    mesh = _read_mesh(folder)
    contact = {k: _brick_faces(_read_facets(_required(folder, f), mesh.node_ids), mesh)
               for k, f in LIP_FILES.items()}
    fibres = _read_fibres(folder, mesh, contact)
    rigid = {k: _read_obj(folder / f) for k, f in TEETH_FILES.items() if (folder / f).is_file()}
    landmarks = _landmarks(mesh.nodes, mesh.node_sets["midsagittal"],
                           contact["upper_lip"], contact["lower_lip"])
    return Anatomy(name="reference", mesh=mesh, fibres=fibres, landmarks=landmarks,
                   contact_surfaces=contact, rigid_surfaces=rigid, half=False)


def _required(folder, name):
    path = folder / name
    if not path.is_file():
        raise MeshFileError(path, None, "required file is missing")
    return path


# ---------------------------------------------------------------- fixed-width ANSYS files

def _text_lines(path):
    """Non-blank lines (right-stripped) of a text file and their 1-based numbers (k,)."""
    lines = path.read_text(encoding="latin-1").splitlines()
    keep = [i for i, line in enumerate(lines) if line.strip()]
    return [lines[i].rstrip() for i in keep], np.array(keep, dtype=np.int64) + 1


def _parse_columns(path, lines, numbers, spans, dtype, names):
    """Fixed-width fields of every line, (k, len(spans)) of dtype; a bad field names its line."""
    width = spans[-1][1]
    buf = "".join(line[:width].ljust(width) for line in lines).encode("latin-1")
    table = np.frombuffer(buf, dtype="S1").reshape(len(lines), width)
    out = np.empty((len(lines), len(spans)), dtype=dtype)
    for j, (a, b) in enumerate(spans):
        col = np.ascontiguousarray(table[:, a:b]).view(f"S{b - a}").ravel()
        try:
            out[:, j] = col.astype(dtype)
        except ValueError:
            _raise_bad_field(path, numbers, col, dtype, f"{names[j]} (columns {a + 1}-{b})")
    return out


def _raise_bad_field(path, numbers, col, dtype, what):
    convert = float if np.issubdtype(dtype, np.floating) else int
    for number, text in zip(numbers, col):
        try:
            convert(text)
        except ValueError:
            raise MeshFileError(path, int(number), f"cannot read {what} from "
                                f"{text.decode('latin-1').strip()!r}") from None


def _check_field_counts(path, lines, numbers, first, width, allowed):
    """Refuse lines whose field count (a first field, then fields of width) is not allowed."""
    lengths = np.fromiter(map(len, lines), dtype=np.int64, count=len(lines))
    counts = 1 + -(-(lengths - first) // width)
    bad = np.flatnonzero(~np.isin(counts, allowed))
    if len(bad):
        i = bad[0]
        raise MeshFileError(path, int(numbers[i]), f"expected {' or '.join(map(str, allowed))} "
                            f"fixed-width fields, found {counts[i]}")


def _read_nodes(path):
    """ANSYS NWRITE file -> ids (n,) int64, xyz (n, 3) mm, line numbers (n,)."""
    lines, numbers = _text_lines(path)
    if not lines:
        raise MeshFileError(path, None, "no nodes")
    _check_field_counts(path, lines, numbers, 8, 20, NODE_FIELD_COUNTS)
    ids = _parse_columns(path, lines, numbers, NODE_SPANS[:1], np.int64, ["node id"])[:, 0]
    xyz = _parse_columns(path, lines, numbers, NODE_SPANS[1:], np.float64, ["x", "y", "z"])
    bad = np.flatnonzero(~np.isfinite(xyz).all(axis=1))
    if len(bad):
        raise MeshFileError(path, int(numbers[bad[0]]), "non-finite coordinate")
    _check_unique(path, ids, numbers, "node")
    return ids, xyz, numbers


def _read_elements(path):
    """ANSYS EWRITE file -> fields (m, 14) int64 (I..P, MAT, TYPE, REAL, SECNUM, ESYS, id),
    line numbers (m,)."""
    lines, numbers = _text_lines(path)
    if not lines:
        raise MeshFileError(path, None, "no elements")
    _check_field_counts(path, lines, numbers, 6, 6, (14,))
    fields = _parse_columns(path, lines, numbers, ELEM_SPANS, np.int64, ELEM_FIELDS)
    _check_unique(path, fields[:, 13], numbers, "element")
    return fields, numbers


def _check_unique(path, ids, numbers, what):
    order = np.argsort(ids, kind="stable")
    dup = np.flatnonzero(ids[order][1:] == ids[order][:-1])
    if len(dup):
        i = order[dup[0] + 1]
        raise MeshFileError(path, int(numbers[i]), f"{what} id {ids[i]} is defined twice")


def _lookup(ids, query):
    """Positions of the query ids (any shape) in ids (n,), -1 where absent."""
    order = np.argsort(ids)
    sorted_ids = ids[order]
    pos = np.clip(np.searchsorted(sorted_ids, query), 0, len(ids) - 1)
    return np.where(sorted_ids[pos] == query, order[pos], -1)


def _indices(path, numbers, ids, query, source, owner=None):
    """Positions (like query, whose rows are on lines numbers) of the ids query in ids, the
    ids of the file source. An absent id names its line, and its row's owner: (kind, (k,) ids)."""
    found = _lookup(ids, query)
    if (found < 0).any():
        row = np.argwhere(found < 0)[0]
        node = query[tuple(row)]
        message = (f"{owner[0]} {owner[1][row[0]]} refers to node {node}, which {source} "
                   "does not define" if owner else f"node {node} is not defined in {source}")
        raise MeshFileError(path, int(numbers[row[0]]), message)
    return found


# ---------------------------------------------------------------------------- mesh

def _read_mesh(folder):
    node_path, elem_path = _required(folder, NODE_FILE), _required(folder, ELEM_FILE)
    node_ids, nodes, _ = _read_nodes(node_path)
    fields, numbers = _read_elements(elem_path)
    bricks = _indices(elem_path, numbers, node_ids, fields[:, :8], NODE_FILE,
                      ("element", fields[:, 13]))
    bricks = _orient(nodes, bricks)
    node_sets = {k: _fixed_set(_required(folder, f), node_ids, nodes)
                 for k, f in FIXED_FILES.items()}
    node_sets["fixed"] = np.union1d(node_sets["fixed_skull"], node_sets["fixed_mandible"])
    node_sets["midsagittal"] = np.flatnonzero(np.abs(nodes[:, 0]) < MIDLINE_TOL)
    element_sets = {f"mat_{k}": np.flatnonzero(fields[:, 8] == k) for k in np.unique(fields[:, 8])}
    for name, file in ACTIVE_FILES.items():
        if (folder / file).is_file():
            element_sets[name] = _active_set(folder / file, fields)
    if (folder / REGION_FILE).is_file():
        element_sets["OOP_region"] = _region_set(folder / REGION_FILE, fields[:, 13])
    return Mesh(nodes, bricks, node_sets, element_sets, node_ids, fields[:, 13])


def _orient(nodes, bricks):
    """bricks (m, 8), reordered to the mirror order when every one is inverted (det J < 0
    at its centre)."""
    jac = np.einsum("ak,maj->mjk", shape_gradients(np.zeros(3)), nodes[bricks])
    return bricks[:, MIRROR_ORDER] if (np.linalg.det(jac) < 0).all() else bricks


def _fixed_set(path, node_ids, nodes):
    """Node indices (k,) of a fixed-node file, whose coordinates must match the mesh's."""
    ids, xyz, numbers = _read_nodes(path)
    found = _indices(path, numbers, node_ids, ids, NODE_FILE)
    off = np.abs(nodes[found] - xyz).max(axis=1)
    if (off > FIXED_MATCH_TOL).any():
        i = int(np.argmax(off > FIXED_MATCH_TOL))
        raise MeshFileError(path, int(numbers[i]), f"node {ids[i]} is {off[i]:.3g} mm away "
                            f"from its position in {NODE_FILE}")
    return found


def _region_set(path, element_ids):
    """Brick indices (k,) of an element-id list (one id a line); an id that is no element
    of the mesh is an error naming its line."""
    numbers, ids = [], []
    for number, line in enumerate(path.read_text(encoding="latin-1").splitlines(), 1):
        if line.strip():
            try:
                ids.append(int(line.split()[0]))
            except ValueError:
                raise MeshFileError(path, number, f"{line.strip()!r} is not an element id") \
                    from None
            numbers.append(number)
    pos = _lookup(element_ids, np.array(ids, dtype=np.int64))
    if (pos < 0).any():
        i = int(np.argmax(pos < 0))
        raise MeshFileError(path, numbers[i], f"element {ids[i]} is not in {ELEM_FILE}")
    return pos


def _active_set(path, mesh_fields):
    """Brick indices (k,) listed in an *_active_elements file."""
    fields, numbers = _read_elements(path)
    pos = _lookup(mesh_fields[:, 13], fields[:, 13])
    listed = np.flatnonzero(pos >= 0)
    bad = listed[(mesh_fields[pos[listed], :8] != fields[listed, :8]).any(axis=1)]
    if len(bad):
        raise MeshFileError(path, int(numbers[bad[0]]), f"element {fields[bad[0], 13]} has "
                            f"other nodes than in {ELEM_FILE}")
    return pos[listed]


# ------------------------------------------------------------------------- muscles

_ASSIGN = re.compile(r"^\s*(\w+)\s*\(([^)]*)\)\s*=\s*(\S+)")
_ARITY = {"ACTIV": 1, "FIBER": 3, "NB_FIBERS": 1, "NB_NODES_FIBER": 2}


def _read_macro(path):
    """The macro's fibres: label -> [(node ids (k,), their lines (k,))], in fibre order."""
    labels, nodes, n_fibres, n_nodes = {}, {}, {}, {}
    for number, line in enumerate(path.read_text(encoding="latin-1").splitlines(), 1):
        match = _ASSIGN.match(line.split("!")[0])
        if not match:
            continue
        name, args, value = match.group(1).upper(), match.group(2), match.group(3)
        if name not in _ARITY:
            continue
        try:
            key = tuple(int(a) for a in args.split(","))
            value = value.upper() if name == "ACTIV" else int(value)
            if len(key) != _ARITY[name]:
                raise ValueError
        except ValueError:
            raise MeshFileError(path, number, f"cannot read {line.strip()!r}") from None
        if name == "ACTIV":
            labels[key[0]] = value
        elif name == "FIBER":
            nodes[key] = (value, number)
        elif name == "NB_FIBERS":
            n_fibres[key[0]] = (value, number)
        else:
            n_nodes[key] = (value, number)
    return _macro_fibres(path, labels, nodes, n_fibres, n_nodes)


def _macro_fibres(path, labels, nodes, n_fibres, n_nodes):
    fibres = {}
    for muscle, fibre, k in sorted(nodes):
        fibres.setdefault((muscle, fibre), []).append(k)
    out = {}
    for (muscle, fibre), ks in fibres.items():
        line = nodes[(muscle, fibre, ks[0])][1]
        expected = n_nodes.get((muscle, fibre), (len(ks), None))[0]
        if ks != list(range(1, expected + 1)):
            raise MeshFileError(path, line, f"fibre {fibre} of muscle {muscle} has nodes "
                                f"{ks}, expected 1..{expected}")
        ids, lines = np.array([nodes[(muscle, fibre, k)] for k in ks]).T
        out.setdefault(labels.get(muscle, str(muscle)), []).append((ids, lines))
    for muscle, (count, line) in n_fibres.items():
        label = labels.get(muscle, str(muscle))
        if len(out.get(label, [])) != count:
            raise MeshFileError(path, line, f"{label} should have {count} fibres, the "
                                f"macro defines {len(out.get(label, []))}")
    missing = [m for m in MUSCLE_NAMES if m not in out]
    if missing:
        raise MeshFileError(path, None, f"no fibres for {', '.join(missing)}")
    return out


def _read_fibres(folder, mesh, contact):
    """Fibres of both sides, by muscle (MUSCLE_NAMES order), then left/right, then fibre."""
    macro_path = _required(folder, MACRO_FILE)
    node_path = _required(folder, MUSCLE_NODE_FILE)
    ids, xyz, numbers = _read_nodes(node_path)
    cables = _read_cables(_required(folder, MUSCLE_ELEM_FILE), ids)
    left = {}
    for label, fibres in _read_macro(macro_path).items():
        if label in MUSCLE_NAMES:
            left[label] = [_indices(macro_path, lines, ids, f, MUSCLE_NODE_FILE)
                           for f, lines in fibres]
    mirror = _mirror(node_path, ids, xyz, numbers, np.concatenate(sum(left.values(), [])))
    _check_mirrored_cables(folder / MUSCLE_ELEM_FILE, cables, left, mirror, ids)
    chains = [(m, g) for m in MUSCLE_NAMES for g in left[m] + [mirror[f] for f in left[m]]]
    return _fibres(chains, xyz, mesh, contact)


def _read_cables(path, ids):
    """Undirected cables {(a, b)} (muscles.node positions, a < b) of a muscles.elem file."""
    fields, numbers = _read_elements(path)
    ends = _indices(path, numbers, ids, fields[:, :2], MUSCLE_NODE_FILE, ("cable", fields[:, 13]))
    return {(min(a, b), max(a, b)) for a, b in ends}


def _mirror(path, ids, xyz, numbers, left):
    """Position (n,) of each left node's mirror image, -1 where not asked (left: positions)."""
    right = _lookup(ids, ids[left] + RIGHT_ID_OFFSET)
    on_mid = np.abs(xyz[left, 0]) < MIDLINE_TOL
    right = np.where(right >= 0, right, np.where(on_mid, left, -1))
    if (right < 0).any():
        i = left[np.argmax(right < 0)]
        raise MeshFileError(path, int(numbers[i]), f"cable node {ids[i]} has no mirror "
                            f"node {ids[i] + RIGHT_ID_OFFSET}")
    off = np.linalg.norm(xyz[right] - xyz[left] * [-1.0, 1.0, 1.0], axis=1)
    if (off > MIRROR_TOL).any():
        j = int(np.argmax(off > MIRROR_TOL))
        raise MeshFileError(path, int(numbers[right[j]]), f"cable node {ids[right[j]]} is "
                            f"{off[j]:.3g} mm from the mirror image of node {ids[left[j]]}")
    out = np.full(len(ids), -1)
    out[left] = right
    return out


def _check_mirrored_cables(path, cables, left, mirror, ids):
    """Every left fibre link that is a cable must have its mirrored cable."""
    for fibres in left.values():
        for f in fibres:
            for a, b in zip(f[:-1], f[1:]):
                ma, mb = mirror[a], mirror[b]
                if (min(a, b), max(a, b)) in cables and (min(ma, mb), max(ma, mb)) not in cables:
                    raise MeshFileError(path, None, f"cable {ids[a]}-{ids[b]} has no mirrored "
                                        f"cable {ids[ma]}-{ids[mb]}")


def _fibres(chains, xyz, mesh, contact):
    """Fibre objects of chains [(muscle, muscle-node positions (k,))]."""
    used = np.unique(np.concatenate([c for _, c in chains]))
    fixed = cKDTree(mesh.nodes[mesh.node_sets["fixed"]])
    lips = cKDTree(mesh.nodes[np.unique(np.concatenate([f.ravel() for f in contact.values()]))])
    d_fixed, d_lips = np.zeros(len(xyz)), np.zeros(len(xyz))
    outside = np.zeros(len(xyz), dtype=bool)
    d_fixed[used] = fixed.query(xyz[used])[0]
    d_lips[used] = lips.query(xyz[used])[0]
    distance = _mesh_distance(mesh.nodes, mesh.bricks, xyz[used], margin=2 * OUTSIDE_TOL)
    outside[used] = distance > OUTSIDE_TOL
    out = []
    for muscle, chain in chains:
        insertion = _insertion(d_fixed[chain], d_lips[chain], outside[chain])
        out.append(Fibre(muscle, _side(xyz[chain, 0]), xyz[chain].copy(), insertion))
    return out


def _side(x):
    """'left', 'right' or 'mid' (points on both sides of x = 0, or all on it) of x (k,)."""
    left, right = x.min() < -MIDLINE_TOL, x.max() > MIDLINE_TOL
    return "mid" if left == right else "left" if left else "right"


def _insertion(d_fixed, d_lips, outside):
    """(k,) bool attached points of one fibre, given each point's distance to the fixed
    nodes and the lips (k,) and whether it lies outside the mesh (k,); rule in the module
    docstring."""
    attached = d_fixed <= INSERTION_TOL
    for order in (slice(None), slice(None, None, -1)):
        if outside[order][0] and d_fixed[order][0] < d_lips[order][0]:
            run = np.cumprod(outside[order]).astype(bool)
            attached[order] |= run
    return attached


def _mesh_distance(nodes, bricks, points, margin, iterations=30):
    """(p,) distance of points (p, 3) to the mesh (0 inside; inf farther than margin from
    every brick's box). Per candidate brick: Newton for the natural coordinates, clipped to
    the brick; the distance to that point is an upper bound, exact inside."""
    xe = nodes[bricks]
    lo, hi = xe.min(axis=1) - margin, xe.max(axis=1) + margin
    pi, ei = np.nonzero(((points[:, None] >= lo) & (points[:, None] <= hi)).all(axis=-1))
    dist = np.full(len(points), np.inf)
    if not len(pi):
        return dist
    x, p, xi = xe[ei], points[pi], np.zeros((len(pi), 3))
    for _ in range(iterations):
        r = np.einsum("ka,kaj->kj", shape_functions(xi), x) - p
        jac = np.einsum("kai,kaj->kji", shape_gradients(xi), x)     # dx_j / dxi_i
        step = np.einsum("kij,kj->ki", np.linalg.pinv(jac), r)
        new = np.clip(xi - step, -3.0, 3.0)
        if np.abs(new - xi).max() < 1e-10:
            break
        xi = new
    near = np.einsum("ka,kaj->kj", shape_functions(np.clip(xi, -1.0, 1.0)), x)
    np.minimum.at(dist, pi, np.linalg.norm(near - p, axis=1))
    return dist


# ------------------------------------------------------------------------ surfaces

def _read_facets(path, node_ids):
    """Lip surface facets -> (f, 3) node indices (polygons split into fans)."""
    faces, numbers = [], []
    for number, line in enumerate(path.read_text(encoding="latin-1").splitlines(), 1):
        tokens = line.replace("[", " ").replace("]", " ").split()
        if not tokens:
            continue
        try:
            if tokens[0] != "f" or len(tokens) < 4:
                raise ValueError
            faces.append([int(t) for t in tokens[1:]])
        except ValueError:
            raise MeshFileError(path, number, f"expected 'f a b c', got {line.strip()!r}") from None
        numbers.append(number)
    if not faces:
        raise MeshFileError(path, None, "no facets")
    tris, rows = _fans(faces)
    return _indices(path, np.array(numbers)[rows], node_ids, tris, NODE_FILE)


def _brick_faces(tris, mesh):
    """The lip surface (t, 3) as the bricks' own faces: (f, 4) quads, in the winding of
    their triangles, where two triangles split a face of a brick; a triangle that does
    not is kept as a degenerate quad (a, b, c, c).

    Why: the facets split each brick face along a diagonal, but the tissue's surface is
    the brick's bilinear face, which a warped quad bulges out of either triangle by up
    to half its warp. Contact on the triangles lets a node rest inside the other lip's
    bricks by that much; on the quads, solver.face.terms.contact.centred_triangles follows
    the bilinear face."""
    faces = mesh.bricks[:, BRICK_FACES].reshape(-1, 4)
    faces = faces[np.array([len(set(f)) == 4 for f in faces], dtype=bool)]
    index = {tuple(sorted(t)): i for i, t in enumerate(tris.tolist())}
    partner = -np.ones(len(tris), dtype=np.int64)
    for f in faces.tolist():
        for a, b, c, d in ((0, 1, 2, 3), (1, 2, 3, 0)):        # the two diagonals a-c
            i = index.get(tuple(sorted((f[a], f[b], f[c]))))
            j = index.get(tuple(sorted((f[a], f[c], f[d]))))
            if i is not None and j is not None and partner[i] < 0 and partner[j] < 0:
                partner[i], partner[j] = j, i
                break
    out = []
    for i, t in enumerate(tris.tolist()):
        j = partner[i]
        w = tris[j].tolist()[::-1] if j >= 0 else []
        shared = [k for k in range(3) if (t[k], t[(k + 1) % 3]) in
                  {(w[m], w[(m + 1) % 3]) for m in range(len(w))}]
        if not shared:                      # no partner, or one wound the other way
            out.append(t + [t[2]])
        elif i < j:                         # the shared edge t[k] -> t[k + 1] reversed in w
            k = shared[0]
            out.append(t[:k + 1] + [next(v for v in w if v not in t)] + t[k + 1:])
    return np.array(out, dtype=np.int64).reshape(-1, 4)


def _fans(polygons):
    """Triangles (t, 3) of polygons (lists of >= 3 ids) and each triangle's polygon (t,)."""
    tris, rows = [], []
    for row, poly in enumerate(polygons):
        for j in range(1, len(poly) - 1):
            tris.append([poly[0], poly[j], poly[j + 1]])
            rows.append(row)
    return np.array(tris, dtype=np.int64).reshape(-1, 3), np.array(rows, dtype=np.int64)


def _read_obj(path):
    """Wavefront OBJ -> RigidSurface (vertices (p, 3) mm, triangles (t, 3) 0-based)."""
    vertices, faces, numbers = [], [], []
    for number, line in enumerate(path.read_text(encoding="latin-1").splitlines(), 1):
        tokens = line.split()
        try:
            if tokens[:1] == ["v"]:
                vertices.append([float(t) for t in tokens[1:4]])
                if len(vertices[-1]) != 3:
                    raise ValueError
            elif tokens[:1] == ["f"]:
                faces.append([int(t.split("/")[0]) for t in tokens[1:]])
                numbers.append(number)
                if len(faces[-1]) < 3:
                    raise ValueError
        except ValueError:
            raise MeshFileError(path, number, f"cannot read {line.strip()!r}") from None
    tris, rows = _fans(faces)
    n = len(vertices)
    tris = np.where(tris < 0, tris + n, tris - 1)       # 1-based; negative: relative
    bad = np.flatnonzero(((tris < 0) | (tris >= n)).any(axis=1))
    if len(bad) or not len(tris):
        line = numbers[rows[bad[0]]] if len(bad) else None
        raise MeshFileError(path, line, f"faces must refer to vertices 1..{n}")
    return RigidSurface(np.array(vertices, dtype=np.float64), tris)


# ----------------------------------------------------------------------- landmarks

def _landmarks(nodes, midsagittal, upper, lower):
    """Landmark node indices from the lip surfaces upper, lower (f, 3); rule in the module
    docstring."""
    up, low = np.unique(upper), np.unique(lower)
    up_mid, low_mid = np.intersect1d(up, midsagittal), np.intersect1d(low, midsagittal)
    if not len(up_mid) or not len(low_mid):
        raise MeshError("a lip contact surface has no mid-sagittal node")
    joined = up[cKDTree(nodes[low]).query(nodes[up])[0] <= CORNER_GAP]
    if not len(joined) or nodes[joined, 0].min() >= 0 or nodes[joined, 0].max() <= 0:
        raise MeshError("the lip contact surfaces do not join at both mouth corners")
    y, z = nodes[:, 1], nodes[:, 2]
    return {
        "upper_lip_edge": int(up_mid[np.argmin(z[up_mid])]),
        "lower_lip_edge": int(low_mid[np.argmax(z[low_mid])]),
        "upper_lip_front": int(up_mid[np.argmax(y[up_mid])]),
        "lower_lip_front": int(low_mid[np.argmax(y[low_mid])]),
        "corner_left": int(joined[np.argmin(nodes[joined, 0])]),
        "corner_right": int(joined[np.argmax(nodes[joined, 0])]),
    }
