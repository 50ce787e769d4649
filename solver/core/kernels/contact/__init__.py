r"""Node-on-triangle-surface penalty contact kernels (see solver.face.terms.contact for the
model), by concern: closest-point geometry (.geometry), penalty laws (.laws), loops over
slaves (.assembly); every public name is re-exported here.

Closest point. For a slave point x and a triangle (x_1, x_2, x_3), the closest point is
c = sum_a w_a x_a (barycentric weights w, Ericson's region test) on one feature: the face
(region 0), an edge j = (j, j+1 mod 3) (region 1 + j) or a vertex j (region 4 + j).
Locally c minimises f = 1/2 |x - c(xi)|^2 over the feature's affine hull, c(xi) = x_o +
sum_i xi_i tau_i with tangents tau_i (two on a face, one on an edge, none on a vertex).

Energy and derivatives. With d = x - c, F = 1/2 |d|^2 and the stacked nodes
X = (x, x_1, x_2, x_3), weights N = (1, -w_1, -w_2, -w_3), envelope theorem:

    dF/dX_a = N_a d,
    d2F/dX dX = N N^T (x) I - B M^-1 B^T,        M_ij = tau_i . tau_j,
    B_i[a] = -C_ia d - N_a tau_i                 (3-vector block of node a),

where tau_i = sum_a C_ia X_a. This is exact, includes the rotation of the face normal and
the motion of the closest point, and needs no division by |d|. For a rigid master only
the slave block is kept: d2F/dx dx = I - sum_ij tau_i M^-1_ij tau_j, which is n n on a
face, I - t t on an edge and I at a vertex.

Side. The signed gap is g = -|d| when (x - c) . N_f <= 0 for the pseudo-normal N_f of the
closest feature (face normal, mean of the two face normals of an edge, angle-weighted
normal of a vertex), +|d| otherwise; g <= 0 is active. A closest point on a free boundary
edge or vertex of an open surface has no side: such a node is out of contact on a rigid
master; on a deformable one (and beyond an edge of a slave's candidate set) its penalty
fades out beyond the edge (boundary_penalty: psi(a) phi(l / L) with the depth a behind
the nearest triangle's plane and the distance l beyond it, C1 where it meets the face;
on a deformable master with that plane's normal held fixed in the force, faded_pair;
in a rim vertex's region with a normal blended over the vertex's fan, vertex_pair).

Penalty. With the penetration p = -g (signed: negative outside), psi(p) is k p^2 / 2 =
k F for p >= 0 (pure penalty; a touching node, p = 0, carries the stiffness k hess F but no
force) or, with a smoothing length s > 0, k (p + s)^3 / (12 s) over -s < p < s joined (C2)
to k (p^2 / 2 + s^2 / 6) (penalty_law): the contact begins at a gap s with no stiffness and
no kink. In terms of u = +-d / |d| (the direction of growing penetration) grad psi =
psi' N (x) u and hess psi = psi'' (N (x) u)(N (x) u)^T + (psi' / |d|) (hess F - (N (x) u)
(N (x) u)^T) (pair_penalty); the bracket is O(|d|) on a face, so the last term stays
bounded there; on an edge or a vertex it is taken over max(|d|, s).
"""

from solver.core.kernels.contact.assembly import (NO_PAIR_FREE, rest_offsets, rigid_contact,
                                                  surface_contact)
from solver.core.kernels.contact.geometry import (closest_point, distance_derivatives, EDGE,
                                                  extend_points, FACE, locate, min_facing,
                                                  nearest, pair_distances, rim_normal,
                                                  signed_gaps, surface_normals,
                                                  surface_normals_part, VERTEX)
from solver.core.kernels.contact.laws import (ALIGN_HI, ALIGN_LO, boundary_penalty,
                                              FADED_STEP, faded_pair, pair_penalty,
                                              penalty_law, vertex_fan, vertex_pair)

__all__ = ["ALIGN_HI", "ALIGN_LO", "EDGE", "FACE", "FADED_STEP", "NO_PAIR_FREE", "VERTEX",
           "boundary_penalty", "closest_point", "distance_derivatives", "extend_points",
           "faded_pair", "locate", "min_facing", "nearest", "pair_distances", "pair_penalty",
           "penalty_law", "rest_offsets", "rigid_contact", "rim_normal", "signed_gaps",
           "surface_contact", "surface_normals", "surface_normals_part", "vertex_fan",
           "vertex_pair"]
