"""Half face: keep x <= 0; the solver then applies u_x = 0 on the mid-sagittal nodes.

Bricks with every node at x <= tol are kept; fibres of the left side are kept (a fibre
must not cross x = 0); landmarks on the right are dropped ('corner_right'): full-face
outputs follow by symmetry. Contact faces and rigid surfaces are restricted likewise
(rigid surfaces keep the triangles with a vertex at x <= tol).
"""


import numpy as np

from solver.face.anatomy.base import Anatomy, RigidSurface


def half_anatomy(anatomy, tol=1e-6):
    """The x <= 0 half of a full anatomy."""
    if anatomy.half:
        return anatomy
    mesh = anatomy.mesh
    keep = np.all(mesh.nodes[mesh.bricks, 0] <= tol, axis=1)
    sub, old = mesh.submesh(keep)
    new = -np.ones(mesh.n_nodes, dtype=np.int64)
    new[old] = np.arange(len(old))
    landmarks = {k: int(new[v]) for k, v in anatomy.landmarks.items() if new[v] >= 0}
    faces = {}
    for k, f in anatomy.contact_surfaces.items():
        f = np.asarray(f)
        ok = np.all(new[f] >= 0, axis=1)
        faces[k] = new[f[ok]]
    rigid = {}
    for k, s in anatomy.rigid_surfaces.items():
        t = s.triangles[np.any(s.vertices[s.triangles, 0] <= tol, axis=1)]
        used, t = np.unique(t, return_inverse=True)
        rigid[k] = RigidSurface(s.vertices[used], t.reshape(-1, 3))
    fibres = [f for f in anatomy.fibres if np.all(f.points[:, 0] <= tol)]
    return Anatomy(anatomy.name, sub, fibres, landmarks, faces, rigid, half=True)
