"""The pictures: head-to-feet front and back renders, a colour per fabric, readable material captions,
and a batch gallery with one tile per garment. A synthetic body (a standing capsule, feet at y = 0) and
an open tube as the garment keep every render tiny and fast."""

from __future__ import annotations

from dataclasses import replace
from itertools import combinations
from types import SimpleNamespace

import matplotlib.image as mpimg
import numpy as np
import pytest

from physdrape.physics.material import Material
from physdrape.physics.presets import MATERIAL_PRESETS
from physdrape.render import FABRIC_RGB, compose_gallery, fabric_color, material_sweep_figure, render_result
from physdrape.render.colors import stiffness_coordinate
from physdrape.render.figures import HEM_RGB, PAD
from physdrape.render.hem import hem_azimuth, hem_drop, hem_loop
from physdrape.render.layout import text_width
from physdrape.render.raster import project, render_view

HEIGHT = 1.7  # body height [m]


def _tube(radius: float, y0: float, y1: float, *, segments: int = 24, rings: int = 6, top_radius: float | None = None):
    """An open cylinder (a cone frustum with `top_radius`) about the y axis from y0 (radius) to y1:
    verts (V, 3), faces (F, 3)."""
    t = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ys = np.linspace(y0, y1, rings)
    radii = np.linspace(radius, radius if top_radius is None else top_radius, rings)
    verts = np.array([[r * np.cos(a), y, r * np.sin(a)] for y, r in zip(ys, radii) for a in t])
    faces = []
    for r in range(rings - 1):
        for s in range(segments):
            a, b = r * segments + s, r * segments + (s + 1) % segments
            faces += [[a, b + segments, b], [a, a + segments, b + segments]]
    return verts, np.array(faces)


def _result(material: Material = MATERIAL_PRESETS["cotton"], name: str = "tube", pose: str = "stand", *,
            drop: float = 0.0):
    """A drape-result stand-in: a flared tube (the hem at y = 0.8 m at X_init) on a capsule body,
    dropped by `drop` [m] from its X_init."""
    import trimesh

    body = trimesh.creation.capsule(height=HEIGHT - 0.3, radius=0.15, count=[16, 16])
    body.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0]))
    body.apply_translation([0.0, HEIGHT / 2, 0.0])  # standing, feet at y = 0, head at y = HEIGHT
    x_init, faces = _tube(0.22, 0.8, 1.4, top_radius=0.18)
    verts = x_init - np.array([0.0, drop, 0.0])
    return SimpleNamespace(
        name=name, pose=pose, verts=verts, faces=faces, x_init=x_init, body_verts=np.asarray(body.vertices),
        body_faces=np.asarray(body.faces), material=material, vertex_residual=np.full(len(verts), 0.1),
        inside_faces=np.zeros(len(faces), bool),
        metrics={"strain": 1e-3, "bend": 2e-4, "b2g_percent": 0.0, "mean_y": 1.1})


def _content(img: np.ndarray) -> np.ndarray:
    """Mask of the pixels that are not white background, (H, W) bool."""
    return (img[..., :3] < 0.97).any(-1)


def test_body_bounds_are_as_built():
    res = _result()
    assert res.body_verts[:, 1].min() == pytest.approx(0.0, abs=1e-6)
    assert res.body_verts[:, 1].max() == pytest.approx(HEIGHT, abs=1e-6)


@pytest.mark.parametrize("mode", ["shaded", "residual"])
def test_render_shows_head_to_feet_front_and_back(tmp_path, mode):
    size = 96
    img = mpimg.imread(render_result(_result(), tmp_path / "r.png", size=size, mode=mode))
    height = img.shape[0]
    view = _content(img[height - PAD - size:height - PAD])  # the views' band: `size` px above the margin
    rows = np.flatnonzero(view.any(1))
    assert rows[0] > 0 and rows[-1] < size - 1, "head or feet touch the view's edge (cut off)"
    assert rows[-1] - rows[0] > 0.85 * size, "the body should fill the view from head to feet"
    cols = np.flatnonzero(view[: size // 2].any(0))  # above the legs: one torso per view
    runs = 1 + np.count_nonzero(np.diff(cols) > 1)
    assert runs >= 2, "a front and a back view side by side"


def test_each_preset_has_its_own_stable_colour():
    colours = {name: fabric_color(m) for name, m in MATERIAL_PRESETS.items()}
    assert set(colours) == set(FABRIC_RGB)
    for a, b in combinations(colours, 2):
        assert np.abs(colours[a] - colours[b]).max() > 0.15, f"{a} and {b} look alike"
    np.testing.assert_array_equal(fabric_color(Material()), colours["cotton"])  # equal material, same colour


def test_custom_material_colour_follows_its_stiffness():
    cotton, denim = MATERIAL_PRESETS["cotton"], MATERIAL_PRESETS["denim"]
    between = replace(cotton, k_bend=1e-4, density=0.3)
    assert stiffness_coordinate(cotton) < stiffness_coordinate(between) < stiffness_coordinate(denim)
    colour = fabric_color(between)
    ends = np.stack([fabric_color(cotton), fabric_color(denim)])
    lo, hi = ends.min(0), ends.max(0)
    assert np.all(colour >= lo - 1e-12) and np.all(colour <= hi + 1e-12)
    assert not np.allclose(colour, fabric_color(cotton)) and not np.allclose(colour, fabric_color(denim))
    np.testing.assert_array_equal(colour, fabric_color(replace(cotton, k_bend=1e-4, density=0.3)))
    extreme = Material(mu=1e9, lam=1e9, k_bend=1.0, density=5.0)  # far outside: clipped to leather's end
    np.testing.assert_allclose(fabric_color(extreme), FABRIC_RGB["leather"])


def _chroma(rgb: np.ndarray) -> np.ndarray:
    """Colour without brightness (shading scales all channels alike)."""
    return rgb / rgb.sum(-1, keepdims=True)


def test_two_presets_render_in_their_fabric_colours(tmp_path):
    size = 64
    views = []
    for name in ("silk", "leather"):
        img = mpimg.imread(render_result(_result(MATERIAL_PRESETS[name]), tmp_path / f"{name}.png", size=size))
        views.append(img[img.shape[0] - PAD - size:img.shape[0] - PAD, :, :3])  # below the captions
    silk, leather = views
    garment = np.abs(silk - leather).max(-1) > 0.2  # same body, same frame: only the garment differs
    assert garment.sum() > 50
    for img, name in ((silk, "silk"), (leather, "leather")):
        mean = _chroma(img[garment]).mean(0)
        own = np.abs(mean - _chroma(np.array(FABRIC_RGB[name]))).sum()
        other = np.abs(mean - _chroma(np.array(FABRIC_RGB["leather" if name == "silk" else "silk"]))).sum()
        assert own < 0.05 < other


def test_material_captions_do_not_overlap(tmp_path):
    results = [_result(m) for m in MATERIAL_PRESETS.values()]
    path = material_sweep_figure(results, list(MATERIAL_PRESETS), tmp_path / "m.png", size=48)
    width = mpimg.imread(path).shape[1]
    widest = max(text_width(f"E_bend {2e-4:.3g} J · E_strain {1e-3:.3g} J", 10.0), text_width("μ 63 kPa · λ 90 kPa", 10.0),
                 text_width("hem drop 0.00 cm (spread 0.00)", 10.0))
    assert width >= len(results) * widest, "each panel is at least as wide as its captions"
    with pytest.raises(ValueError, match="one label per result"):
        material_sweep_figure(results, ["silk"], tmp_path / "x.png", size=48)


def test_hem_is_the_longest_opening_and_its_drop_is_measured_from_x_init():
    x_init, faces = _tube(0.22, 0.8, 1.4, top_radius=0.18, segments=24, rings=6)
    hem = hem_loop(faces, x_init)
    assert len(hem) == 24 and np.allclose(x_init[hem, 1], 0.8), "the wider (lower) opening is the hem"
    top = hem_loop(faces, x_init * np.array([1.0, -1.0, 1.0]))  # flipped upside down: the wide end is still the hem
    np.testing.assert_array_equal(np.sort(top), np.sort(hem))
    even, even_faces = _tube(0.2, 0.8, 1.4)
    assert np.allclose(even[hem_loop(even_faces, even), 1], 0.8), "equal openings: the lower one"
    verts = x_init.copy()
    verts[hem, 1] -= np.where(np.arange(len(hem)) % 2 == 0, 0.01, 0.03)  # a rippled hem, 2 cm down on average
    drop = hem_drop(verts, x_init, hem)
    assert drop.mean == pytest.approx(0.02) and drop.spread == pytest.approx(0.01)
    assert hem_drop(x_init + np.array([0.5, -0.04, 0.2]), x_init, hem).mean == pytest.approx(0.04)
    azimuth = hem_azimuth(x_init, hem)
    front = hem[np.argmin(np.abs(azimuth))]
    assert x_init[front, 2] == pytest.approx(x_init[hem, 2].max()), "azimuth 0 is the front (+z)"
    with pytest.raises(ValueError, match="no opening"):
        hem_loop(np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]]), np.eye(4, 3))


def test_projection_lands_on_the_rendered_mesh():
    res = _result()
    frame, size, yaw = (-0.5, 0.5, 0.0, HEIGHT), 96, 30.0
    img = render_view([{"verts": res.body_verts, "faces": res.body_faces, "colors": (0.2, 0.2, 0.2)}], yaw_deg=yaw,
                      size=size, frame=frame)
    body = _content(img)
    pix = project(res.body_verts, yaw_deg=yaw, size=size, frame=frame)
    rows, cols = np.flatnonzero(body.any(1)), np.flatnonzero(body.any(0))
    assert abs(pix[:, 1].min() - rows[0]) <= 1.5 and abs(pix[:, 1].max() - (rows[-1] + 1)) <= 1.5
    assert abs(pix[:, 0].min() - cols[0]) <= 1.5 and abs(pix[:, 0].max() - (cols[-1] + 1)) <= 1.5


def _gold(img: np.ndarray) -> np.ndarray:
    return (np.abs(img[..., :3] - np.array(HEM_RGB)) < 0.15).all(-1)


def test_sweep_marks_each_hem_where_it_hangs(tmp_path):
    size, drop = 160, 0.08
    results = [_result(MATERIAL_PRESETS["silk"]), _result(MATERIAL_PRESETS["leather"], drop=drop)]
    img = mpimg.imread(material_sweep_figure(results, ["silk", "leather"], tmp_path / "m.png", size=size))
    top = PAD + 30  # the views' band starts under the title
    views = img[top - 10:top + size + 10]
    gold = _gold(views)
    half = views.shape[1] // 2
    rows = [np.flatnonzero(gold[:, :half].any(1)), np.flatnonzero(gold[:, half:].any(1))]
    assert all(r.size for r in rows), "each panel shows its hem line"
    frame = np.array([a for a in (results[0].verts, results[1].verts)]).reshape(-1, 3)
    expected = drop * size / (1.06 * (HEIGHT - (frame[:, 1].min() - 0.12)))  # drop [m] × px per m of the shared frame
    assert np.median(rows[1]) - np.median(rows[0]) == pytest.approx(expected, rel=0.3)
    assert _gold(img[top + size + 10:]).sum() == 0, "captions and chart carry no hem line"


def test_batch_gallery_has_a_tile_per_garment(tmp_path):
    size = 40
    renders = []
    for k, material in enumerate(list(MATERIAL_PRESETS.values()) * 2):
        renders.append(render_result(_result(material, name=f"g{k}"), tmp_path / f"r{k}.png", size=size))
    details = [renders[0], renders[0]]
    single = mpimg.imread(compose_gallery(details, tmp_path / "one.png"))
    heights = []
    for n in (1, 4, 5, 8):
        path = compose_gallery(details, tmp_path / f"g{n}.png", heading="first garment: g0 [stand]",
                               batch=renders[:n], batch_captions=[f"g{k} [stand]" for k in range(n)])
        heights.append(mpimg.imread(path).shape[0])
    assert single.shape[0] < heights[0] and single.shape[0] < heights[1] < heights[2] == heights[3]  # 4 a row
    with pytest.raises(ValueError, match="one caption per batch picture"):
        compose_gallery(details, tmp_path / "x.png", batch=renders[:2], batch_captions=["only one"])


def _reference_rasterise(screen, faces, height, width):
    """The z-buffer by brute force: every pixel centre against every triangle (barycentrics as
    `rasterise` forms them), the nearest wins and, of equally near ones, the first in claim order."""
    from physdrape.render.raster import _claim_order

    order = _claim_order(screen, faces)
    face_id = np.full((height, width), -1, np.int64)
    bary = np.zeros((height, width, 3))
    best = np.full((height, width), np.inf)
    rank = np.full((height, width), np.iinfo(np.int64).max)
    cy, cx = np.mgrid[:height, :width] + 0.5
    for f, (a, b, c) in enumerate(np.asarray(screen, np.float64)[faces]):
        den = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1])
        if abs(den) <= 1e-12:
            continue
        w0 = ((b[1] - c[1]) * (cx - c[0]) + (c[0] - b[0]) * (cy - c[1])) / den
        w1 = ((c[1] - a[1]) * (cx - c[0]) + (a[0] - c[0]) * (cy - c[1])) / den
        w2 = 1.0 - w0 - w1
        z = w0 * a[2] + w1 * b[2] + w2 * c[2]
        take = (w0 >= -1e-9) & (w1 >= -1e-9) & (w2 >= -1e-9) & ((z < best) | ((z == best) & (order[f] < rank)))
        best[take], rank[take], face_id[take] = z[take], order[f], f
        bary[take] = np.stack([w0, w1, w2], -1)[take]
    return face_id, bary


@pytest.mark.parametrize("seed", [0, 1])
def test_rasterise_equals_a_brute_force_z_buffer_with_its_tie_rule(seed):
    from physdrape.render.raster import rasterise

    rng = np.random.default_rng(seed)
    n = 120
    screen = np.c_[rng.uniform(-10, 70, (n, 2)), rng.uniform(0.0, 1.0, n)]
    screen[: n // 2, 2] = 0.5  # coplanar triangles at one depth: ties decided by the claim order
    faces = np.r_[rng.integers(0, n // 2, (40, 3)), rng.integers(0, n, (60, 3)), [[0, 0, 1]]]  # and a degenerate one
    face_id, bary = rasterise(screen, faces, 48, 56)
    want_id, want_bary = _reference_rasterise(screen, faces, 48, 56)
    assert (face_id >= 0).mean() > 0.5 and len(np.unique(face_id)) > 20
    np.testing.assert_array_equal(face_id, want_id)
    np.testing.assert_allclose(bary, want_bary, rtol=0, atol=1e-12)
