"""Tiny meshes whose energies are known in closed form."""

import math

import numpy as np
import pytest
import torch

from physdrape.geometry.garment import Garment
from physdrape.geometry.primitives import grid_sheet
from physdrape.physics import Cloth, Material, bend_energy, dihedral_angle, internal_forces, strain_energy
from physdrape.physics.forces import energy_terms

MAT = Material()


def test_one_triangle_uniaxial_stretch():
    rest = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.0, 0.1]])
    tri = Garment.from_mesh(rest, np.array([[0, 1, 2]]))
    cloth = Cloth.build(tri, MAT)
    s = 1.2
    x = tri.rest * torch.tensor([s, 1.0, 1.0], dtype=torch.float64)
    g_xx = 0.5 * (s * s - 1.0)  # Green strain along the stretch, all other components zero
    psi = MAT.mu * g_xx**2 + 0.5 * MAT.lam * g_xx**2
    expected = MAT.thickness * 0.005 * psi
    assert float(strain_energy(x, cloth)[0]) == pytest.approx(expected, rel=1e-12)


def test_one_triangle_shear():
    rest = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.0, 0.1]])
    tri = Garment.from_mesh(rest, np.array([[0, 1, 2]]))
    cloth = Cloth.build(tri, MAT)
    k = 0.1  # simple shear: x += k·z; F = [[1, k], [0, 1]] in the frame (x, z)
    x = tri.rest.clone()
    x[:, 0] += k * x[:, 2]
    G = 0.5 * np.array([[0.0, k], [k, k * k]])
    psi = MAT.mu * (G**2).sum() + 0.5 * MAT.lam * np.trace(G) ** 2
    assert float(strain_energy(x, cloth)[0]) == pytest.approx(MAT.thickness * 0.005 * psi, rel=1e-12)


@pytest.mark.parametrize("angle_deg", [10.0, 45.0, 90.0, 150.0])
def test_one_hinge_with_known_angle(angle_deg):
    # Two unit right triangles on the shared edge x ∈ [0, 1]; fold the second one by `angle`.
    phi = math.radians(angle_deg)
    rest = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    faces = np.array([[0, 1, 2], [1, 0, 3]])
    hinge = Garment.from_mesh(rest * 0.1, faces)
    cloth = Cloth.build(hinge, MAT)
    x = hinge.rest.clone()
    x[3] = 0.1 * torch.tensor([0.0, math.sin(phi), math.cos(phi)], dtype=torch.float64)
    theta = dihedral_angle(x, hinge.hinges)
    assert abs(float(theta[0])) == pytest.approx(phi, rel=1e-12)
    # l₀² / (4(A₀ + A₁)) = 0.01 / (4 · 0.01) = 1/4
    assert float(bend_energy(x, cloth)[0]) == pytest.approx(MAT.k_bend * 0.25 * phi**2 / 2, rel=1e-12)
    # Folding the other way gives the opposite sign and the same energy.
    x[3, 1] *= -1
    assert float(dihedral_angle(x, hinge.hinges)[0]) == pytest.approx(-float(theta[0]), rel=1e-12)


def test_small_square_sheet_gravity_and_uniform_stretch():
    verts, faces = grid_sheet(4, 4, width=0.3, height=0.3)
    sheet = Garment.from_mesh(verts, faces)
    cloth = Cloth.build(sheet, MAT)
    assert float(cloth.mass.sum()) == pytest.approx(MAT.density * 0.09, rel=1e-12)
    lifted = sheet.rest + torch.tensor([0.0, 1.5, 0.0], dtype=torch.float64)
    terms = energy_terms(lifted, cloth)
    assert float(terms["gravity"][0]) == pytest.approx(MAT.density * 0.09 * MAT.gravity * 1.5, rel=1e-12)
    # Uniform isotropic stretch by s: G = (s² − 1)/2 · I everywhere, ψ = μ·2g² + λ/2·(2g)².
    s = 1.1
    g = 0.5 * (s * s - 1.0)
    psi = MAT.mu * 2 * g * g + 0.5 * MAT.lam * (2 * g) ** 2
    assert float(terms["strain"][0]) == pytest.approx(0.0)
    stretched = energy_terms(sheet.rest * s, cloth)
    assert float(stretched["strain"][0]) == pytest.approx(MAT.thickness * 0.09 * psi, rel=1e-12)
    assert float(stretched["bend"][0]) == pytest.approx(0.0, abs=1e-20)
    # Uniform stretch: interior forces cancel, only the boundary is pulled inward.
    f = internal_forces(sheet.rest * s, cloth) - cloth.mass[:, None] * cloth.gravity[0]
    interior = [5, 6, 9, 10]
    assert f[interior].abs().max() < 1e-9 * f.abs().max()


def test_material_from_young_poisson_matches_snug_defaults():
    m = Material.from_young_poisson(7e4, 0.485)
    assert m.mu == pytest.approx(2.36e4, rel=2e-3)
    assert m.lam == pytest.approx(4.44e4, rel=2e-3)
    assert m.k_bend == pytest.approx(3.96e-5, rel=2e-3)
    with pytest.raises(ValueError, match="Poisson"):
        Material.from_young_poisson(7e4, 0.5)
    with pytest.raises(ValueError, match="mu must be positive"):
        Material(mu=-1.0)
