r"""Frictionless penalty contact: lips on the rigid teeth, lip on lip.

Both terms are node-on-surface: a slave node x meets a triangulated master surface. c is
the closest point of the master's candidate triangles to x, d = x - c, and the signed gap
is g = -|d| if (x - c) . N <= 0, else +|d| (N the pseudo-normal of the closest face, edge
or vertex; n = -d / |d| the outward normal for g < 0). Per slave node i, with the
stiffness k_i = penalty * A_i (A_i the node's area, a quarter of each of its boundary
faces; penalty in N/mm^3):

    Psi_i = 1/2 k_i g^2 (g <= 0, else 0),   dPsi/dx = k_i d,   d2Psi/dx dx = k_i (I - dc/dx)

(k_i n n on a face, k_i (I - t t) on an edge, k_i I at a vertex; a deformable master
triangle's nodes get their share by the envelope theorem, solver.core.kernels.contact). A
node pressed with the force f penetrates by f / k_i: pure penalty, PENALTY = 1 N/mm^3 lip
on lip (a scene's lip_penalty), TEETH_PENALTY = 2 N/mm^3. Beyond a free edge of an open
sheet the penalty fades out over L = fade (1 mm), Psi_i = psi(a) phi(l / L); optionally
(smoothing s > 0 mm, off by default) the law is smoothed over |g| < s (penalty_law).

RigidContact: lips and cheeks on the rigid teeth. The sheet is oriented towards the
tissue; slaves behind it at rest by more than rest_tolerance, or not facing it, are
dropped (.dropped). Candidates: the triangles within search_radius (a cKDTree of their
centroids), rebuilt once a slave has moved by more than margin. ``rest_offset`` (on by
default) gives a slave that the law pushes on at rest a constant offset (.offset) to where
it is force-free: the anatomy as given is the rest state. Rigid surfaces that share a
seam are joined into one term (joined_surfaces).

LipContact: two passes (upper-lip nodes on the lower lip's triangles, and the reverse).
Each lip quad is cut 2 x 2 and each part into four triangles around its centre
(centred_triangles, pair_maps). Candidate pairs (facing triangles within radius, at most
max_pairs a slave) are picked at rest and again at every commit (follow_state); the
sparsity pattern is made again only when a candidate leaves it (blocks_generation) and is
part of the state (pattern_state). Penetrations deeper than depth (0.5 mm) are ignored.

After each assembly both terms hold: gap (s,) signed gaps (inf: no candidate or a free
boundary), force (s,) normal contact forces (N), n_active, max_penetration (mm, >= 0),
total_force (N) and nodal_force (n, 3). ``linear_gaps(u)`` gives each slave's penetration
and its gradient (Newton's contact status prediction, solver.core.contact_update).

Derivation, free edges and rims, the penalty choice, both terms in full: docs/method.md,
section 'Contact: lips on lips, lips and cheeks on the teeth'. Modules: base (penalty
constants, reports), surfaces, search (candidates), rigid, lips; build_contact_terms here.
"""

import numpy as np

from solver.face.terms.contact.base import (EDGE_FADE, FACING_TOLERANCE, PENALTY,
                                            TEETH_PENALTY, TOLERANCE)
from solver.face.terms.contact.lips import LipContact
from solver.face.terms.contact.rigid import RigidContact
from solver.face.terms.contact.search import nodes_near, surface_distance
from solver.face.terms.contact.surfaces import (centred_triangles, jaw_motion,
                                                joined_surfaces, pair_maps, tributary_areas)

__all__ = ["EDGE_FADE", "FACING_TOLERANCE", "PENALTY", "TEETH_PENALTY", "TOLERANCE",
           "LipContact", "RigidContact", "build_contact_terms", "centred_triangles",
           "joined_surfaces", "nodes_near", "pair_maps", "surface_distance",
           "tributary_areas"]


def build_contact_terms(anatomy, lips=True, teeth=True, teeth_distance=3.0, rest_offset=True,
                        lip_penalty=None, jaw=None, **options):
    """The contact terms of an Anatomy: a RigidContact per rigid surface (surfaces that
    share a seam joined: joined_surfaces; named after the surface, with '_contact';
    slaves: the movable nodes of the mesh boundary within teeth_distance (mm) of it at
    rest: the inner lip and cheek surfaces; rest_offset as RigidContact's) when teeth, a
    LipContact when lips (mirrored on the 'midsagittal' nodes of a half anatomy), with
    lip_penalty (N/mm^3) where given; options go to every term (penalty, smoothing). jaw
    (solver.face.jaw.Jaw):
    the lower teeth's vertices follow its pose (those that the upper teeth share, on a
    seam, stay with the upper: the lower sheet's first row stretches over the gap).
    """
    mesh, surfaces = anatomy.mesh, anatomy.contact_surfaces
    terms = []
    if teeth:
        nodes = np.setdiff1d(np.unique(mesh.boundary_faces()), mesh.node_sets.get("fixed", []))
        for name, surface in joined_surfaces(anatomy.rigid_surfaces).items():
            motion = jaw_motion(anatomy.rigid_surfaces, surface, jaw)
            teeth = dict({"penalty": TEETH_PENALTY}, **options)
            terms.append(RigidContact(mesh, nodes_near(mesh, nodes, surface, teeth_distance),
                                      surface, name=f"{name}_contact",
                                      rest_offset=rest_offset, motion=motion, **teeth))
    if lips:
        mirror = mesh.node_sets["midsagittal"] if anatomy.half else None
        lip = dict(options, **({} if lip_penalty is None else {"penalty": lip_penalty}))
        terms.append(LipContact(mesh, surfaces["upper_lip"], surfaces["lower_lip"],
                                mirror_nodes=mirror, **lip))
    return terms
