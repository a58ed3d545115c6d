"""A plane moment frame as sparse mass and stiffness matrices with one influence matrix per storey.

``storeys x bays`` frame of Euler-Bernoulli beam-column elements (axial and bending, 3 DOFs a node:
``u`` horizontal, ``v`` vertical, ``r`` rotation), each member meshed into ``elements`` elements,
fixed at the base; consistent element mass matrices plus a lumped floor mass at every beam-column
joint. The stiffness is ``K(theta) = K0 + sum_j theta_j K_j`` with ``K_j`` the columns of storey ``j``
(their ``EA`` and ``EI`` scale together) and ``K0`` the beams: the form
:class:`~seqbayes.structural.structures.linear.LinearModel` takes. The sensors are the horizontal
DOFs of the left column at every floor.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["FrameMatrices", "plane_frame"]


@dataclass(frozen=True)
class FrameMatrices:
    """The frame's matrices (``n`` free DOFs) and where its sensors are.

    Attributes
    ----------
    mass, stiffness0 : (n, n) sparse
    influence : tuple of (n, n) sparse
        ``K_j`` of storey ``j`` = 1 .. ``storeys``.
    observed : (storeys,) int array
        The left column's horizontal DOF at each floor, bottom to top.
    channels : tuple of str
        ``"floor1" ..``.
    nodes : (n_nodes, 2) array
        Node coordinates [m] (the free ones; DOF ``3 i + c`` of node ``i``).
    """

    mass: sp.csc_matrix
    stiffness0: sp.csc_matrix
    influence: tuple
    observed: np.ndarray
    channels: tuple
    nodes: np.ndarray

    @property
    def n_dofs(self) -> int:
        return self.mass.shape[0]


def _element(xy0, xy1, EA, EI, rho_a):
    """Global stiffness and consistent mass (6 x 6) of a 2-D frame element from ``xy0`` to ``xy1``."""
    dx, dy = np.subtract(xy1, xy0)
    L = float(np.hypot(dx, dy))
    c, s = dx / L, dy / L
    a, b1, b2, b3 = EA / L, 12 * EI / L ** 3, 6 * EI / L ** 2, EI / L
    k = np.array([[a, 0, 0, -a, 0, 0],
                  [0, b1, b2, 0, -b1, b2],
                  [0, b2, 4 * b3, 0, -b2, 2 * b3],
                  [-a, 0, 0, a, 0, 0],
                  [0, -b1, -b2, 0, b1, -b2],
                  [0, b2, 2 * b3, 0, -b2, 4 * b3]])
    m0 = rho_a * L
    m = m0 / 420 * np.array([[140, 0, 0, 70, 0, 0],
                             [0, 156, 22 * L, 0, 54, -13 * L],
                             [0, 22 * L, 4 * L ** 2, 0, 13 * L, -3 * L ** 2],
                             [70, 0, 0, 140, 0, 0],
                             [0, 54, 13 * L, 0, 156, -22 * L],
                             [0, -13 * L, -3 * L ** 2, 0, -22 * L, 4 * L ** 2]])
    T = np.zeros((6, 6))
    for i in (0, 3):
        T[i:i + 2, i:i + 2] = [[c, s], [-s, c]]
        T[i + 2, i + 2] = 1.0
    return T.T @ k @ T, T.T @ m @ T


def plane_frame(storeys: int = 10, bays: int = 3, storey_height: float = 3.5, bay_width: float = 6.0,
                elements: int = 4, column=(2.0e7, 1.0e5), beam=(1.5e7, 1.5e5), line_mass=(0.4, 0.5),
                floor_mass: float = 20.0) -> FrameMatrices:
    """The frame of the module docstring (units kN, m, t, s).

    Parameters
    ----------
    storeys, bays : int
    storey_height, bay_width : float
        [m].
    elements : int
        Elements per member (a column of one storey, a beam of one bay).
    column, beam : (2,) tuples
        ``(EA [kN], EI [kN m^2])`` of the columns and beams.
    line_mass : (2,) tuple
        Mass per length [t/m] of the columns and beams.
    floor_mass : float
        Lumped mass [t] at each beam-column joint (horizontal and vertical).

    Returns
    -------
    FrameMatrices

    Examples
    --------
    >>> frame = plane_frame()
    >>> frame.n_dofs, len(frame.influence)
    (750, 10)
    """
    if storeys < 1 or bays < 1 or elements < 1:
        raise ValueError(f"storeys, bays, elements: expected positive integers, got {storeys}, {bays}, {elements}")
    index = {}

    def node(x, y):
        key = (round(x, 9), round(y, 9))
        if key not in index:
            index[key] = len(index)
        return index[key]

    members = []                             # (node a, node b, group: storey 1..n or 0 for beams, kind)
    for j in range(storeys):
        for col in range(bays + 1):
            x = col * bay_width
            ys = np.linspace(j * storey_height, (j + 1) * storey_height, elements + 1)
            ids = [node(x, y) for y in ys]
            members += [(ids[e], ids[e + 1], j + 1, "column") for e in range(elements)]
        y = (j + 1) * storey_height
        for bay in range(bays):
            xs = np.linspace(bay * bay_width, (bay + 1) * bay_width, elements + 1)
            ids = [node(x, y) for x in xs]
            members += [(ids[e], ids[e + 1], 0, "beam") for e in range(elements)]
    coords = np.array(sorted(index, key=index.get), dtype=float)
    fixed = coords[:, 1] == 0.0
    free_ids = -np.ones(len(coords), dtype=int)
    free_ids[~fixed] = np.arange(int((~fixed).sum()))
    n = 3 * int((~fixed).sum())
    groups = {g: ([], [], []) for g in range(storeys + 1)}
    m_rows, m_cols, m_vals = [], [], []
    for a, b, group, kind in members:
        EA, EI = column if kind == "column" else beam
        ke, me = _element(coords[a], coords[b], EA, EI, line_mass[0] if kind == "column" else line_mass[1])
        dofs = np.array([3 * free_ids[a] + i if free_ids[a] >= 0 else -1 for i in range(3)]
                        + [3 * free_ids[b] + i if free_ids[b] >= 0 else -1 for i in range(3)])
        keep = dofs >= 0
        r, c = np.meshgrid(dofs[keep], dofs[keep], indexing="ij")
        rows, cols, vals = groups[group]
        rows.append(r.ravel()), cols.append(c.ravel()), vals.append(ke[np.ix_(keep, keep)].ravel())
        m_rows.append(r.ravel()), m_cols.append(c.ravel()), m_vals.append(me[np.ix_(keep, keep)].ravel())
    joints = [free_ids[node(col * bay_width, (j + 1) * storey_height)] for j in range(storeys) for col in range(bays + 1)]
    for i in joints:                          # floor masses at the joints, horizontal and vertical
        m_rows.append([3 * i, 3 * i + 1]), m_cols.append([3 * i, 3 * i + 1]), m_vals.append([floor_mass, floor_mass])

    def assemble(rows, cols, vals):
        return sp.csc_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n))

    mass = assemble(m_rows, m_cols, m_vals)
    stiffness0 = assemble(*groups[0])
    influence = tuple(assemble(*groups[g]) for g in range(1, storeys + 1))
    observed = np.array([3 * free_ids[node(0.0, (j + 1) * storey_height)] for j in range(storeys)])
    return FrameMatrices(mass, stiffness0, influence, observed, tuple(f"floor{j + 1}" for j in range(storeys)),
                         coords[~fixed])
