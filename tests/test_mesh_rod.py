"""A rod given as a closed mesh (a spoon, a paddle): its sampled signed distance, and a stir with it."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
import trimesh

from diffstir.mpm import SimConfig, StirringSimulator
from diffstir.mpm.boundaries import CylinderRod, MeshRod
from diffstir.rheology import Newtonian
from diffstir.rig import Rig, Rod
from diffstir.trajectory import circle

RADIUS, LENGTH = 0.0125, 0.2  # m, the paper's rod
SECTIONS = 128  # the polygon's sides: it lies within R (1 − cos(π/128)) = 3.8 µm of the circle


@pytest.fixture(scope="module")
def cylinder_mesh(tmp_path_factory) -> str:
    """The paper's rod as a closed triangle mesh in the rod's frame (tip at z = 0, axis along z), an STL file."""
    mesh = trimesh.creation.cylinder(radius=RADIUS, height=LENGTH, sections=SECTIONS)
    mesh.apply_translation([0.0, 0.0, LENGTH / 2])
    path = tmp_path_factory.mktemp("mesh") / "rod.stl"
    mesh.export(path)
    return str(path)


def test_a_cylinder_mesh_has_the_cylinders_signed_distance_and_normal(cylinder_mesh):
    """Sampled every h = 2.5 mm (a quarter of the paper's cell, as ``rod_shape`` samples it) and interpolated
    trilinearly: within two samples of the rod's side, where φ is smooth with curvature 1/R, the error is of order
    h² / R per axis, under h / 10 at h / R = 0.2, and the normal within 3° of the cylinder's; anywhere in the
    sampled box (three samples beyond the mesh) but at the tip's rim, interpolation across φ's kinks (inside, where
    the nearest face changes; its gradient turns by 90°) errs by at most √2 h / 4. Beyond the box φ is only
    "outside", four samples."""
    h = 0.0025
    rod = MeshRod(cylinder_mesh, spacing=h)
    assert rod.radius == pytest.approx(RADIUS, rel=1e-6)
    rng = np.random.default_rng(0)
    r = RADIUS + rng.uniform(-0.010, 2.9 * h, 8000)
    angle = rng.uniform(0, 2 * math.pi, r.size)
    z = rng.uniform(-2.9 * h, 0.15, r.size)
    points = torch.tensor(np.stack([r * np.cos(angle), r * np.sin(angle), z], 1))
    phi, normal = rod.sdf(points)
    phi_c, normal_c = CylinderRod(RADIUS).sdf(points)
    error = (phi - phi_c).abs().numpy()
    side = (np.abs(r - RADIUS) < 2 * h) & (z > 2 * h + np.abs(r - RADIUS))
    rim = (np.abs(r - RADIUS) < 2 * h) & (np.abs(z) < 2 * h)
    assert error[side].max() < h / 10
    assert error[~rim].max() < math.sqrt(2) * h / 4
    cosine = (normal * normal_c).sum(1).numpy()[side]
    assert cosine.min() > math.cos(math.radians(3.0))
    far = torch.tensor([[0.0, 0.0, -0.05]], dtype=torch.float64)
    assert float(rod.sdf(far)[0]) == pytest.approx(4 * h)


def test_a_stir_with_the_cylinder_mesh_reads_the_cylinder(cylinder_mesh):
    """The paper's 3-D grid, a short stir: the mesh rod and the cylinder rod give the same drag within 5 %: the
    sampled surface lies within h / 10 = 0.25 mm of the cylinder's (above), 2 % of its radius, and a rod's drag
    goes as its radius to a power of 1-3 in the closed forms. The mesh's sampled field is
    converted to the particles' device and precision once, not at every step."""
    config = SimConfig(dim=3, dx=0.01, sound_speed=4.5, settle_time=0.1)
    trajectory = circle(radius=0.015, speed=0.05, duration=0.05, ramp_time=0.02)
    forces = []
    for rod in (Rod(), Rod(mesh=cylinder_mesh)):
        sim = StirringSimulator(Newtonian(eta=1.0), Rig(rod=rod), config, density=1000.0)
        with torch.no_grad():
            forces.append(sim(trajectory).force[:, :2].norm(dim=1).mean().item())
    assert forces[1] == pytest.approx(forces[0], rel=0.05)
    assert len(sim.scene.rod._fields) == 1


def test_an_open_mesh_and_a_mesh_in_millimetres_are_refused(tmp_path):
    open_mesh = trimesh.creation.cylinder(radius=RADIUS, height=LENGTH, sections=16)
    open_mesh.update_faces(np.arange(len(open_mesh.faces)) > 4)  # a hole in the cap
    open_mesh.export(tmp_path / "open.stl")
    with pytest.raises(ValueError, match="watertight"):
        MeshRod(str(tmp_path / "open.stl"), spacing=0.0025)
    millimetres = trimesh.creation.cylinder(radius=12.5, height=200.0, sections=16)
    millimetres.export(tmp_path / "mm.stl")
    with pytest.raises(ValueError, match="millimetres"):
        MeshRod(str(tmp_path / "mm.stl"), spacing=0.0025)
