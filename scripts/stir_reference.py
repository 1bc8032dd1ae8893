"""An independent reference for the 2-D stir: incompressible Navier-Stokes by finite elements (docs/validation.md).

The MLS-MPM simulator's closed-form checks (Couette, a rod translating at 1 mm/s) are creeping flows. The stirs that
recordings hold are not: a rod on a 15 mm circle at 0.1 m/s runs at Re = ρ U 2a / η = 1-50, with inertia, a wake and
the fluid spinning up around the cup. This script computes that flow by another method, with no particles, no grid
transfers and no compressibility, to say how far the simulator's force is from the physics it stands for.

Method. In the frame that turns with the rod's orbit (angle θ(t), rate Ω = θ', the rod's centre at (e, 0)), the
domain between the cup (radius b, centre 0) and the rod (radius a) is fixed. There the relative velocity u solves

    ρ (∂u/∂t + u·∇u + 2 Ω ẑ × u + Ω' ẑ × x − Ω² x) = −∇p + ∇·(2 η D(u)),    ∇·u = 0,

with u = −Ω ẑ × x on the cup (at rest in the lab) and u = (ω − Ω) ẑ × (x − c) on the rod (ω its own spin in the lab,
0 for a stirring rod that does not turn). Taylor-Hood elements (P2 velocity, P1 pressure, scikit-fem) on a
structured mesh in bipolar coordinates (polar for e = 0), second-order backward differences in time with the
convection, Coriolis and Euler terms extrapolated (SBDF2), one sparse LU factorisation per run. The force on the rod
is the consistent reaction: the residual of the discrete momentum equation at the rod's velocity degrees of freedom,
which is the traction ∮ σ n of the true pressure (the centrifugal term is a body force, not absorbed in p). The
Couette check (e = 0, Ω = 0, ω given) reproduces 4π η ω a² b² / (b² − a²) to 2e-4 on the default mesh.

    python scripts/stir_reference.py --viscosity 0.2 --out ref_0.2.npz [--speed 0.1 --orbit 0.015 --duration 1.5]
    python scripts/stir_reference.py --couette                       # the solver's own closed-form check

Output (``--out``): times [s], force on the rod [N/m] along the orbit's radius (outwards) and along the rod's motion,
its torque about its own axis [N], the fluid's angular momentum about the cup's axis [kg m²/s per m], and the run's
parameters. Needs scikit-fem (``pip install -e ".[validation]"``).
"""

from __future__ import annotations

import argparse
import math
import time

import numpy as np
from scipy.optimize import brentq
from scipy.sparse.linalg import splu
from skfem import (Basis, BilinearForm, ElementTriP1, ElementTriP2, ElementVector, Functional, LinearForm, MeshTri, asm,
                   bmat)
from skfem.helpers import ddot, div, dot, grad, sym_grad


def annulus_mesh(a: float, b: float, e: float, n_around: int, n_across: int) -> tuple[MeshTri, np.ndarray]:
    """Triangles between the cup (radius b [m], centre 0) and the rod (radius a [m], centre (e, 0)): a structured
    mesh in bipolar coordinates (polar for e = 0), ``n_around`` nodes on each circle and ``n_across`` cells between.
    Returns the mesh and the node indices of its rings, (n_across + 1, n_around), the rod's ring first."""
    s = np.linspace(0.0, 1.0, n_across + 1)
    angle = np.linspace(0.0, 2 * np.pi, n_around, endpoint=False)
    if e == 0:
        r, phase = np.meshgrid(a + (b - a) * s, angle, indexing="ij")
        x, y = r * np.cos(phase), r * np.sin(phase)
    else:  # circles τ = const of bipolar coordinates with foci ±α: centres α coth τ, radii α / sinh τ
        alpha = brentq(lambda al: math.hypot(al, b) - math.hypot(al, a) - e, 1e-12, 1e3)
        tau_cup, tau_rod = math.asinh(alpha / b), math.asinh(alpha / a)
        tau, sigma = np.meshgrid(tau_rod + (tau_cup - tau_rod) * s, angle, indexing="ij")
        scale = alpha / (np.cosh(tau) - np.cos(sigma))
        x = -(scale * np.sinh(tau) - alpha / math.tanh(tau_cup))  # cup centre to the origin, rod on +x
        y = -scale * np.sin(sigma)
    rings = np.arange(x.size).reshape(x.shape)
    here, nxt = rings[:-1], np.roll(rings[:-1], -1, axis=1)
    out, out_nxt = rings[1:], np.roll(rings[1:], -1, axis=1)
    triangles = np.concatenate([np.stack([here, out, out_nxt]).reshape(3, -1),
                                np.stack([here, out_nxt, nxt]).reshape(3, -1)], axis=1)
    points = np.stack([x.ravel(), y.ravel()])
    corners = points[:, triangles]
    area = ((corners[0, 1] - corners[0, 0]) * (corners[1, 2] - corners[1, 0])
            - (corners[0, 2] - corners[0, 0]) * (corners[1, 1] - corners[1, 0]))
    triangles[1:, area < 0] = triangles[2:0:-1, area < 0]  # counter-clockwise
    return MeshTri(points, triangles), rings


class StirReference:
    """The flow between the cup and a rod whose axis orbits the cup's axis at distance ``e`` [m].

    Args:
        a, b, e: rod radius, cup radius, orbit radius [m].
        density: ρ [kg/m³]; viscosity: η [Pa·s] (Newtonian).
        n_around, n_across: the mesh (``annulus_mesh``).
    """

    def __init__(self, a: float, b: float, e: float, density: float, viscosity: float, *, n_around: int = 160,
                 n_across: int = 32):
        self.a, self.b, self.e, self.density, self.viscosity = a, b, e, density, viscosity
        self.mesh, rings = annulus_mesh(a, b, e, n_around, n_across)
        self.velocity = Basis(self.mesh, ElementVector(ElementTriP2()), intorder=4)
        self.pressure = Basis(self.mesh, ElementTriP1(), intorder=4)
        boundary = self.mesh.boundary_facets()
        on_rod = np.isin(self.mesh.facets[:, boundary], rings[0]).all(0)
        rod, cup = self.velocity.get_dofs(boundary[on_rod]), self.velocity.get_dofs(boundary[~on_rod])
        self.rod_dofs = (rod.all("u^1"), rod.all("u^2"))
        self.cup_dofs = (cup.all("u^1"), cup.all("u^2"))
        self.n_u, self.n_p = self.velocity.N, self.pressure.N
        self.mass = asm(BilinearForm(lambda u, v, w: dot(u, v)), self.velocity)
        self.stiffness = asm(BilinearForm(lambda u, v, w: 2.0 * ddot(sym_grad(u), sym_grad(v))), self.velocity)
        self.divergence = asm(BilinearForm(lambda u, q, w: div(u) * q), self.velocity, self.pressure)
        # Dirichlet velocity on both walls, and one pressure value (the pressure is otherwise defined up to a constant)
        self.fixed = np.concatenate([*self.rod_dofs, *self.cup_dofs, [self.n_u]])
        self.free = np.setdiff1d(np.arange(self.n_u + self.n_p), self.fixed)

    def wall_velocity(self, orbit_rate: float, spin: float) -> np.ndarray:
        """Velocity of the walls relative to the turning frame at the boundary dofs [m/s], (n_u,)."""
        x = self.velocity.doflocs
        values = np.zeros(self.n_u)
        cx, cy = self.cup_dofs
        values[cx], values[cy] = orbit_rate * x[1, cx], -orbit_rate * x[0, cy]
        rx, ry = self.rod_dofs
        values[rx], values[ry] = -(spin - orbit_rate) * x[1, rx], (spin - orbit_rate) * (x[0, ry] - self.e)
        return values

    def run(self, times: np.ndarray, orbit_rate, orbit_acceleration, spin) -> np.ndarray:
        """Integrate from rest over uniform ``times`` [s]; ``orbit_rate`` Ω(t) [rad/s], ``orbit_acceleration`` Ω'(t)
        [rad/s²] and ``spin`` ω(t) [rad/s] are functions of time. Returns, per step, the force on the rod [N/m]
        along the orbit's radius and along the orbit's direction of motion, its torque about its own axis [N], and
        the fluid's angular momentum about the cup's axis in the lab, ρ ∫ x × (u + Ω ẑ × x) dA [kg m²/s per m],
        (len(times) − 1, 4)."""
        dt = float(times[1] - times[0])
        rho, x = self.density, self.velocity.doflocs

        @LinearForm
        def explicit(v, w):  # ρ (u·∇u + 2 Ω ẑ × u)
            u = w["u"]
            advection = np.einsum("ij...,j...->i...", grad(u), u)
            return rho * dot(advection + 2 * w["rate"] * np.stack([-u[1], u[0]]), v)

        @LinearForm
        def frame(v, w):  # ρ (Ω² x − Ω' ẑ × x): the centrifugal and Euler forces of the turning frame
            p = w.x
            return rho * dot(np.stack([w["accel"] * p[1] + w["rate"] ** 2 * p[0],
                                       -w["accel"] * p[0] + w["rate"] ** 2 * p[1]]), v)

        def solver(weight):
            matrix = bmat([[weight * rho / dt * self.mass + self.viscosity * self.stiffness, -self.divergence.T],
                           [-self.divergence, None]], "csr")
            return matrix, splu(matrix[self.free][:, self.free].tocsc()), matrix[self.free][:, self.fixed]

        rx, ry = self.rod_dofs
        moment = asm(LinearForm(lambda v, w: w.x[0] * v[1] - w.x[1] * v[0]), self.velocity)  # ∫ x × u dA = moment·u
        polar = asm(Functional(lambda w: w.x[0] ** 2 + w.x[1] ** 2), self.velocity)  # ∫ |x|² dA
        u_old, u_now, advected_old = np.zeros(self.n_u), np.zeros(self.n_u), None
        out = np.zeros((len(times) - 1, 4))
        for n in range(len(times) - 1):
            t_now, t_next = times[n], times[n + 1]
            if n < 2:  # backward Euler on the first step, then BDF2
                matrix, lu, coupling = solver(1.0 if n == 0 else 1.5)
            advected = asm(explicit, self.velocity, u=self.velocity.interpolate(u_now), rate=orbit_rate(t_now))
            if n == 0:
                rhs = rho / dt * (self.mass @ u_now) - advected
            else:
                rhs = rho / (2 * dt) * (self.mass @ (4 * u_now - u_old)) - (2 * advected - advected_old)
            rhs = rhs + asm(frame, self.velocity, rate=orbit_rate(t_next), accel=orbit_acceleration(t_next))
            rhs = np.concatenate([rhs, np.zeros(self.n_p)])
            solution = np.zeros(self.n_u + self.n_p)
            solution[: self.n_u] = self.wall_velocity(orbit_rate(t_next), spin(t_next))
            solution[self.free] = lu.solve(rhs[self.free] - coupling @ solution[self.fixed])
            reaction = matrix @ solution - rhs  # the rod's force on the fluid at its dofs
            torque = ((x[0, ry] - self.e) * reaction[ry]).sum() - (x[1, rx] * reaction[rx]).sum()
            spin_up = rho * (moment @ solution[: self.n_u] + orbit_rate(t_next) * polar)
            out[n] = -reaction[rx].sum(), -reaction[ry].sum(), -torque, spin_up
            u_old, u_now, advected_old = u_now, solution[: self.n_u], advected
        return out


def cosine_ramp(t, ramp_time: float):
    """0 → 1 over ``ramp_time`` [s] (diffstir.trajectory's ramp) and its rate [1/s]."""
    s = np.clip(t / ramp_time, 0.0, 1.0)
    rate = np.where((t > 0) & (t < ramp_time), 0.5 * np.pi / ramp_time * np.sin(np.pi * s), 0.0)
    return 0.5 - 0.5 * np.cos(np.pi * s), rate


def stir(viscosity: float, *, speed: float = 0.1, orbit: float = 0.015, duration: float = 1.5, ramp_time: float = 0.5,
         rod_radius: float = 0.0125, cup_radius: float = 0.0425, density: float = 1000.0, step: float = 0.002,
         n_around: int = 160, n_across: int = 32) -> dict:
    """The rod stirred along ``diffstir.trajectory.circle(orbit, speed, duration, ramp_time=ramp_time)``."""
    reference = StirReference(rod_radius, cup_radius, orbit, density, viscosity, n_around=n_around, n_across=n_across)
    rate = speed / orbit
    times = np.linspace(0.0, duration, int(round(duration / step)) + 1)
    force = reference.run(times, lambda t: rate * cosine_ramp(t, ramp_time)[0],
                          lambda t: rate * cosine_ramp(t, ramp_time)[1], lambda t: 0.0)
    return {"times": times[1:], "radial": force[:, 0], "tangential": force[:, 1], "torque": force[:, 2],
            "angular_momentum": force[:, 3],
            "viscosity": viscosity, "density": density, "speed": speed, "orbit": orbit, "rod_radius": rod_radius,
            "cup_radius": cup_radius, "ramp_time": ramp_time, "step": step, "mesh": (n_around, n_across),
            "dofs": reference.n_u + reference.n_p}


def couette(viscosity: float = 1.0, spin: float = 2.0, *, rod_radius: float = 0.0125, cup_radius: float = 0.0425,
            n_around: int = 160, n_across: int = 32) -> tuple[float, float]:
    """Steady torque on a rod spinning at the cup's centre [N], and the closed form 4π η ω a² b² / (b² − a²)."""
    reference = StirReference(rod_radius, cup_radius, 0.0, 1000.0, viscosity, n_around=n_around, n_across=n_across)
    times = np.linspace(0.0, 2.0, 201)
    torque = reference.run(times, lambda t: 0.0, lambda t: 0.0, lambda t: spin * cosine_ramp(t, 0.1)[0])[-1, 2]
    a, b = rod_radius, cup_radius
    return -torque, 4 * math.pi * viscosity * spin * a**2 * b**2 / (b**2 - a**2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--viscosity", type=float, help="η [Pa·s]")
    parser.add_argument("--speed", type=float, default=0.1, help="rod speed on its circle [m/s]")
    parser.add_argument("--orbit", type=float, default=0.015, help="radius of the rod's circle [m]")
    parser.add_argument("--duration", type=float, default=1.5, help="[s]")
    parser.add_argument("--step", type=float, default=0.002, help="time step [s]")
    parser.add_argument("--mesh", type=int, nargs=2, default=(160, 32), metavar=("AROUND", "ACROSS"))
    parser.add_argument("--out", help="an .npz file for the force history")
    parser.add_argument("--couette", action="store_true", help="check the solver against the Couette closed form")
    args = parser.parse_args()
    start = time.time()
    if args.couette:
        torque, exact = couette(n_around=args.mesh[0], n_across=args.mesh[1])
        print(f"Couette torque {torque:.6g} N, closed form {exact:.6g} N, ratio {torque / exact:.5f} "
              f"({time.time() - start:.0f} s)")
        return
    if args.viscosity is None or args.out is None:
        parser.error("--viscosity and --out are needed (or --couette)")
    result = stir(args.viscosity, speed=args.speed, orbit=args.orbit, duration=args.duration, step=args.step,
                  n_around=args.mesh[0], n_across=args.mesh[1])
    np.savez(args.out, **result)
    late = result["times"] > 0.6 * args.duration
    print(f"η = {args.viscosity} Pa·s: drag {-result['tangential'][late].mean():.4f} N/m, radial force "
          f"{result['radial'][late].mean():+.4f} N/m over the last 40 %; {result['dofs']} dofs, "
          f"{time.time() - start:.0f} s -> {args.out}")


if __name__ == "__main__":
    main()
