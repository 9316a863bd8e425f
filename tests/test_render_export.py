"""Tests of sim.render (PNG/GIF pictures of a run file) and sim.vtk_export (.vtu frames + .pvd).

The run files are small synthetic NPZs written here; results are checked against the arrays written,
never against the exporter's own output.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

import meshio
import numpy as np
import pytest
from PIL import Image

from sim.render import render, render_before_after
from sim.vtk_export import export_vtk

F = 6
TAB10_C0 = np.array([31, 119, 180])  # colour of object 0
TAB10_C1 = np.array([255, 127, 14])  # colour of object 1


def _edges_of(cells: np.ndarray) -> np.ndarray:
    k = cells.shape[1]
    pairs = np.concatenate([cells[:, [i, j]] for i in range(k) for j in range(i + 1, k)])
    return np.unique(np.sort(pairs, axis=1), axis=0).astype(np.int64)


def _run(nodes, edges, cells, node_object, cell_object, names, pinned, floor, scene, n_frames=F, seed=0):
    """Arrays of a run in which the last node moves by a growing offset and everything else is still."""
    rng = np.random.default_rng(seed)
    D = nodes.shape[1]
    x = np.repeat(nodes[None].astype(np.float64), n_frames, axis=0)
    x[:, -1, 0] += np.linspace(0.0, 0.05, n_frames)
    v = rng.normal(size=x.shape)
    return dict(
        t=np.linspace(0.0, 0.01 * (n_frames - 1), n_frames), x=x, v=v,
        a=rng.uniform(0.5, 1.5, size=(n_frames, len(edges))),
        edges=np.asarray(edges, np.int64), cells=np.asarray(cells, np.int64).reshape(-1, D + 1),
        node_object=np.asarray(node_object, np.int64), cell_object=np.asarray(cell_object, np.int64),
        object_names=np.array(names), pinned=np.asarray(pinned, bool), dim=np.int64(D),
        scene=np.str_(scene), floor_height=np.float64(floor), mass=np.full(len(nodes), 1e-3),
    )


def strip_2d(**kw):
    """A 2D strip of four triangles (two objects), node 5 moving, floor below."""
    nodes = np.array([[0, 0], [0.1, 0], [0, 0.1], [0.1, 0.1], [0, 0.2], [0.1, 0.2]], float)
    cells = np.array([[0, 1, 3], [0, 3, 2], [2, 3, 5], [2, 5, 4]])
    return _run(nodes, _edges_of(cells), cells, [0, 0, 0, 0, 1, 1], [0, 0, 1, 1], ["lower", "upper"],
                [1, 1, 0, 0, 0, 0], -0.05, "strip", **kw)


def tetra_pair_3d(**kw):
    """Two tetrahedra sharing a face, node 4 moving, floor at z = 0."""
    nodes = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [0, 0, 0.1], [0.1, 0.1, 0.1]], float)
    cells = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    return _run(nodes, _edges_of(cells), cells, np.zeros(5), [0, 0], ["pair"], [1, 0, 0, 0, 0], 0.0,
                "tetra pair", **kw)


def chain_2d(**kw):
    """A single element between two nodes: no cells, no floor."""
    nodes = np.array([[0.0, 0.0], [0.1, 0.02]])
    return _run(nodes, [[0, 1]], np.zeros((0, 3)), [0, 0], [], ["chain"], [1, 0], np.nan, "chain", **kw)


SCENES = {"strip_2d": strip_2d, "tetra_pair_3d": tetra_pair_3d, "chain_2d": chain_2d}


def write_npz(tmp_path, name, arrays) -> str:
    path = tmp_path / f"{name}.npz"
    np.savez(path, **arrays)
    return str(path)


@pytest.fixture(params=sorted(SCENES))
def scene(request, tmp_path):
    arrays = SCENES[request.param]()
    return request.param, arrays, write_npz(tmp_path, request.param, arrays)


def _colour_pixels(img: Image.Image, rgb: np.ndarray, tol: int = 40) -> int:
    px = np.asarray(img.convert("RGB"), dtype=np.int64)
    return int(np.sum(np.all(np.abs(px - rgb) <= tol, axis=-1)))


# ------------------------------------------------------------------------------------------- PNG


def test_png_is_written_and_shows_the_elements(scene, tmp_path):
    name, arrays, npz = scene
    out = tmp_path / "pics" / f"{name}.png"
    assert render(npz, out) == out
    with Image.open(out) as img:
        assert img.format == "PNG"
        assert img.width > 0 and img.height > 0
        # elements are drawn in the colour of object 0 (and 1 for the two-object strip)
        assert _colour_pixels(img, TAB10_C0) > 50
        if name == "strip_2d":
            assert _colour_pixels(img, TAB10_C1) > 50


def test_png_draws_floor_and_pinned_nodes(tmp_path):
    def count(arrays, name, rgb, tol):
        with Image.open(render(write_npz(tmp_path, name, arrays), tmp_path / f"{name}.png")) as img:
            return _colour_pixels(img, np.array(rgb), tol)

    grey = (128, 128, 128)
    with_floor = strip_2d()
    without_floor = strip_2d()
    without_floor["floor_height"] = np.float64(np.nan)
    # the floor is a grey line across each of the 4 panels (limits differ a little, hence the margin)
    assert count(with_floor, "floor", grey, 3) > count(without_floor, "nofloor", grey, 3) + 300

    pinned = chain_2d()
    free = chain_2d()
    free["pinned"][:] = False  # same limits and ticks, only the markers differ
    assert count(pinned, "pinned", (0, 0, 0), 10) > count(free, "free", (0, 0, 0), 10) + 20


def test_png_frames_choose_the_panels(tmp_path):
    npz = write_npz(tmp_path, "strip", strip_2d())
    widths = {}
    for key, frames in {"one": 1, "two": [0, -1], "default": None, "six": list(range(F))}.items():
        out = render(npz, tmp_path / f"{key}.png", frames=frames)
        with Image.open(out) as img:
            widths[key] = img.width
    assert widths["one"] < widths["two"] < widths["default"] < widths["six"]


@pytest.mark.parametrize("frames", [[0, F], [-F - 1], [1.5], [], 0, -2, True])
def test_bad_frames_raise_value_error(tmp_path, frames):
    npz = write_npz(tmp_path, "strip", strip_2d())
    with pytest.raises(ValueError):
        render(npz, tmp_path / "bad.png", frames=frames)
    assert not (tmp_path / "bad.png").exists()


def test_render_before_after(tmp_path):
    npz = write_npz(tmp_path, "strip", strip_2d())
    out = render_before_after(npz, tmp_path / "ba.png", [0, 3, -1], ["before press", "pressed", "after"])
    with Image.open(out) as img:
        assert img.format == "PNG" and img.width > img.height > 0
    with pytest.raises(ValueError, match="label"):
        render_before_after(npz, tmp_path / "ba2.png", [0, 1], ["only one"])
    with pytest.raises(ValueError, match="out of range"):
        render_before_after(npz, tmp_path / "ba3.png", [0, 99], ["a", "b"])
    with pytest.raises(ValueError, match="unsupported output format '.gif'"):
        render_before_after(npz, tmp_path / "ba.gif", [0, 1], ["a", "b"])


# ------------------------------------------------------------------------------------------- GIF


def test_gif_is_an_animation_of_every_frame(scene, tmp_path):
    name, arrays, npz = scene
    out = render(npz, tmp_path / f"{name}.gif")
    with Image.open(out) as img:
        assert img.format == "GIF"
        assert img.width > 0 and img.height > 0
        assert img.n_frames == F
        img.seek(0)
        first = np.asarray(img.convert("RGB")).copy()
        img.seek(F - 1)
        last = np.asarray(img.convert("RGB"))
        assert first.shape == last.shape
        assert np.any(first != last)  # the moving node and the time label change


def test_gif_is_subsampled_to_at_most_max_frames(tmp_path, monkeypatch):
    import sim.render

    assert sim.render.MAX_GIF_FRAMES == 200
    # a 200-frame GIF takes seconds: check the subsampling with a smaller cap
    monkeypatch.setattr(sim.render, "MAX_GIF_FRAMES", 10)
    npz = write_npz(tmp_path, "chain", chain_2d(n_frames=23))
    with Image.open(render(npz, tmp_path / "long.gif")) as img:
        assert img.n_frames == 10
    with Image.open(render(npz, tmp_path / "chosen.gif", frames=[0, 5, 22])) as img:
        assert img.n_frames == 3


# ------------------------------------------------------------------------------------------- errors


@pytest.mark.parametrize("suffix", [".jpg", ".svg", ""])
def test_unsupported_suffix(tmp_path, suffix):
    npz = write_npz(tmp_path, "strip", strip_2d())
    with pytest.raises(ValueError) as exc:
        render(npz, tmp_path / f"picture{suffix}")
    assert str(exc.value) == f"unsupported output format '{suffix}': use .png or .gif"


def test_missing_file(tmp_path):
    missing = tmp_path / "nope.npz"
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        render(missing, tmp_path / "x.png")
    with pytest.raises(FileNotFoundError, match="nope.npz"):
        export_vtk(missing, tmp_path / "vtk")
    assert not (tmp_path / "vtk").exists()


def test_missing_keys(tmp_path):
    arrays = strip_2d()
    del arrays["edges"], arrays["pinned"]
    npz = write_npz(tmp_path, "broken", arrays)
    with pytest.raises(ValueError, match=r"key\(s\): edges, pinned$"):
        render(npz, tmp_path / "x.png")
    arrays = strip_2d()
    del arrays["a"]
    npz = write_npz(tmp_path, "no_a", arrays)
    render(npz, tmp_path / "ok.png")  # the picture does not need a
    with pytest.raises(ValueError, match=r"key\(s\): a$"):
        export_vtk(npz, tmp_path / "vtk")


def test_unreadable_and_inconsistent_files(tmp_path):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"PK\x03\x04 this is not a zip archive")
    with pytest.raises(ValueError, match="junk.npz"):
        render(junk, tmp_path / "x.png")
    arrays = strip_2d()
    arrays["edges"] = np.array([[0, 6]])  # node 6 does not exist
    with pytest.raises(ValueError, match="edges"):
        export_vtk(write_npz(tmp_path, "bad_edges", arrays), tmp_path / "vtk")
    arrays = strip_2d()
    arrays["a"] = arrays["a"][:, :-1]
    with pytest.raises(ValueError, match="a must have shape"):
        export_vtk(write_npz(tmp_path, "bad_a", arrays), tmp_path / "vtk")


# ------------------------------------------------------------------------------------------- VTK


def test_export_writes_every_frame_and_a_pvd_in_time_order(scene, tmp_path):
    name, arrays, npz = scene
    out_dir = tmp_path / "deep" / "vtk"
    files = export_vtk(npz, out_dir)
    expected = [out_dir / f"frame_{i:05d}.vtu" for i in range(F)]
    assert files == expected
    assert all(p.is_file() and p.stat().st_size > 0 for p in expected)

    root = ET.parse(out_dir / "run.pvd").getroot()
    assert root.tag == "VTKFile" and root.get("type") == "Collection"
    datasets = root.find("Collection").findall("DataSet")
    assert [d.get("file") for d in datasets] == [p.name for p in expected]
    times = [float(d.get("timestep")) for d in datasets]
    assert times == arrays["t"].tolist()
    assert all(t0 < t1 for t0, t1 in zip(times, times[1:]))


@pytest.mark.parametrize("frame", [0, 3])
def test_vtu_round_trip_matches_the_run_file(scene, tmp_path, frame):
    name, arrays, npz = scene
    files = export_vtk(npz, tmp_path / "vtk")
    mesh = meshio.read(files[frame])
    D = int(arrays["dim"])
    N = arrays["x"].shape[1]

    expected_points = np.zeros((N, 3))
    expected_points[:, :D] = arrays["x"][frame]
    np.testing.assert_array_equal(mesh.points, expected_points)
    expected_v = np.zeros((N, 3))
    expected_v[:, :D] = arrays["v"][frame]
    np.testing.assert_array_equal(mesh.point_data["velocity"], expected_v)
    np.testing.assert_array_equal(mesh.point_data["pinned"], arrays["pinned"].astype(int))
    np.testing.assert_array_equal(mesh.point_data["object"], arrays["node_object"])

    types = [b.type for b in mesh.cells]
    line = types.index("line")
    np.testing.assert_array_equal(mesh.cells[line].data, arrays["edges"])
    np.testing.assert_array_equal(mesh.cell_data["a"][line], arrays["a"][frame])
    cell_type = "triangle" if D == 2 else "tetra"
    if len(arrays["cells"]):
        block = types.index(cell_type)
        np.testing.assert_array_equal(mesh.cells[block].data, arrays["cells"])
        assert np.all(np.isnan(mesh.cell_data["a"][block]))
    else:
        assert cell_type not in types
