"""The scene of a simulation: what stays fixed over a rollout (grid, solids, particles' mass and volume)."""

from __future__ import annotations

from dataclasses import dataclass

from torch import Tensor

from ..rig import Cup
from .boundaries import GhostBand, RodShape, RodWindow
from .grid import Grid
from .implicit_viscosity import StiffnessPattern
from .projection import CellMatrices
from .viscous import CellStencil
from .walls import WallParticles


@dataclass(frozen=True)
class Scene:
    """What stays fixed over a rollout: grid, solids, particle mass and volume, bulk modulus, gravity.

    Everything a step needs that does not change within a rollout is built here once (index tables, constant
    matrices in the simulation's dtype), so that a step constructs no tensors from Python values.

    Attributes:
        grid: the background grid; ``nodes`` the node positions [m] (num_nodes, d), ``strides`` its flat-index
            strides (d,) int64.
        offset_index: flat index offset of each quadratic-stencil node from the particle's base node, (3^d,) int64.
        stencil_points: the stencil's node offsets in cells with a trailing 1, [o_k, 1], (3^d, d + 1).
        eye: the identity matrix, (d, d).
        mass_row: [0, …, 0, particle mass] [kg], (1, 1, d + 1): the mass row of the p2g transfer matrix.
        cells: the grid's cells as finite elements (``viscous.CellStencil``).
        particle_bounds: lowest and highest particle position whose stencil stays on the grid [m], (2, d).
        cup: the cup; ``cup_phi`` its signed distance at every node [m]; ``cup_band`` its solid nodes within reach
            of the fluid with their ghost-fluid probes (``boundaries.GhostBand``).
        rod: the rod's shape; ``rod_slip`` whether its surface is a slip wall; ``rod_window`` the block of nodes
            that holds the rod wherever it is (``boundaries.RodWindow``).
        particle_mass: mass of one particle [kg] (2-D: per unit length [kg/m]).
        particle_volume: rest volume of one particle [m³] (2-D: area [m²]).
        node_mass: the mass a grid node carries inside the fluid at rest, density · dx^d [kg] (2-D: [kg/m]).
        bulk_modulus: κ of the weakly compressible fluid [Pa].
        gravity: acceleration of gravity [m/s²], (d,).
        viscosity_cap: the largest viscosity the explicit step resolves [Pa·s]; above it the fluid is rigid-like.
        rod_slip_length: Navier slip length b of the rod's (no-slip) surface [m]: the fluid slips along it at
            b ∂u_t/∂n; 0 is no-slip (see ``boundaries.ghost_matrix``).
        flip: share of FLIP in the particles' velocity update [1] (``SimConfig.flip``).
        relaxation_rate: 1/τ, the rate at which J relaxes towards the grid's packing [1/s]; 0: not at all.
        solid_mass: the mass the cup's walls and bottom would put on each node if they were fluid at rest [kg]
            (2-D: [kg/m]), (num_nodes,) (``packing.cup_solid_mass``).
        rod_points: virtual particles filling the rod near its surface, in the rod's frame [m], (R, d), each of
            mass ``rod_point_mass`` [kg] (2-D: [kg/m]) (``packing.rod_fill_points``).
        cell_matrices: with an incompressible pressure, the grid's cell operators as sparse matrices
            (``projection.CellMatrices``): the pressure keeps the grid's velocity divergence-free instead of
            following the particles' compression (``bulk_modulus`` is then 0); None: a compressible fluid.
        walls: boundary particles in the solids that carry the fluid's pressure (``walls.WallParticles``); None:
            the solids' nodes see the fluid's pressure only.
        fused: whether the particle-grid transfers run as the fused C++ kernels (``transfer``) or as torch ops.
        viscous_stiffness: with an implicit shear stress (``SimConfig.viscous_solver``), the grid's viscous
            stiffness pattern (``implicit_viscosity.StiffnessPattern``); None: explicit.
    """

    grid: Grid
    offset_index: Tensor
    stencil_points: Tensor
    eye: Tensor
    mass_row: Tensor
    cells: CellStencil
    particle_bounds: Tensor
    strides: Tensor
    nodes: Tensor
    cup: Cup
    cup_phi: Tensor
    cup_band: GhostBand
    rod: RodShape
    rod_window: RodWindow
    rod_slip: bool
    particle_mass: float
    particle_volume: float
    node_mass: float
    bulk_modulus: float
    gravity: Tensor
    viscosity_cap: float
    flip: float
    relaxation_rate: float
    solid_mass: Tensor
    rod_points: Tensor
    rod_point_mass: float
    rod_slip_length: float | Tensor = 0.0
    cell_matrices: CellMatrices | None = None
    walls: WallParticles | None = None
    fused: bool = False
    viscous_stiffness: StiffnessPattern | None = None

    @property
    def dim(self) -> int:
        return self.grid.dim

    @property
    def incompressible(self) -> bool:
        """Whether the pressure is solved by a projection (``cell_matrices`` set)."""
        return self.cell_matrices is not None
