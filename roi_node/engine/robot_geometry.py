"""A robot's link geometry from its URDF, as few triangles per link, for the visibility render.

Each link takes its `<visual>` geometry; where a visual mesh does not load
(a missing file, a format trimesh cannot read), its `<collision>` geometry;
boxes, cylinders and spheres are built here. Meshes are thinned at load by
vertex clustering on a grid of a fixed share of the mesh's size, so a link
costs at most a few hundred triangles per frame whatever its source mesh
holds. A link whose declared geometry loads in neither form is listed in
`unloaded`: a render without it could call a hidden gripper visible, so
visibility is unknown while such a link exists (never a wrong number).

`package://<pkg>/<rest>` is resolved against the URDF's own folders (an
ancestor named `<pkg>`, or an ancestor holding a `<pkg>` folder), then
against the installed example-robot-data, the way rig files name its URDFs.
"""

from __future__ import annotations

import contextlib
import functools
import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from roi_node.engine.errors import KinematicsError
from roi_node.engine.robot_models import example_robot_data_root
from roi_node.engine.transforms import Float64Array, Transform

GRID_CELLS = 10  # clustering grid: cells along the mesh's longest side (a few hundred triangles for a link)
CYLINDER_SIDES = 12
SPHERE_RINGS = 6


@dataclass(frozen=True)
class LinkGeometry:
    """A link's triangles in its own frame: vertices (N x 3, m) and faces (M x 3 vertex indices)."""

    link: str
    vertices_m: Float64Array
    faces: np.ndarray
    source: str  # "visual" or "collision"


@dataclass(frozen=True)
class RobotGeometry:
    links: dict[str, LinkGeometry]
    unloaded: dict[str, str] = field(default_factory=dict)  # link -> why neither its visual nor its collision loaded
    fallbacks: tuple[str, ...] = ()  # links drawn from their collision geometry

    def summary(self, robot_id: str) -> str:
        """One line for the log at start: what the render draws, and what it falls back to."""
        triangles = sum(len(g.faces) for g in self.links.values())
        line = f"visibility: robot {robot_id}: {len(self.links)} links with geometry, {triangles} triangles"
        if self.fallbacks:
            line += f"; collision geometry for {', '.join(self.fallbacks)} (visual mesh did not load)"
        if self.unloaded:
            link, why = next(iter(self.unloaded.items()))
            line += f"; UNKNOWN visibility: {len(self.unloaded)} links without geometry ({link}: {why})"
        return line


def load_robot_geometry(urdf_text: str, urdf_path: Path, grid_cells: int = GRID_CELLS) -> RobotGeometry:
    """Every link's geometry of one URDF (see the module docstring for the order of preference); meshes thinned on a
    grid of `grid_cells` along their longest side."""
    try:
        root = ET.fromstring(urdf_text)
    except ET.ParseError as exc:
        raise KinematicsError(f"{urdf_path}: not valid URDF XML: {exc}") from exc
    links: dict[str, LinkGeometry] = {}
    unloaded: dict[str, str] = {}
    fallbacks: list[str] = []
    for el in root.findall("link"):
        name = el.get("name", "")
        visuals, collisions = el.findall("visual"), el.findall("collision")
        if not visuals and not collisions:
            continue
        problems: list[str] = []
        for kind, elements in (("visual", visuals), ("collision", collisions)):
            if not elements:
                continue
            try:
                links[name] = _link_geometry(name, elements, kind, urdf_path, grid_cells)
            except _GeometryError as exc:
                problems.append(f"{kind}: {exc}")
                continue
            if kind == "collision" and visuals:
                fallbacks.append(name)
            break
        else:
            unloaded[name] = "; ".join(problems)
    return RobotGeometry(links, unloaded, tuple(fallbacks))


class _GeometryError(Exception):
    """One geometry element of a link that cannot be turned into triangles (the message says why)."""


def _link_geometry(link: str, elements: list[ET.Element], kind: str, urdf_path: Path, grid_cells: int) -> LinkGeometry:
    vertices: list[Float64Array] = []
    faces: list[np.ndarray] = []
    count = 0
    for el in elements:
        shape = el.find("geometry")
        if shape is None or len(shape) == 0:
            raise _GeometryError("no <geometry>")
        v, f = _shape_triangles(shape[0], urdf_path, grid_cells)
        v = _origin(el.find("origin")).apply(v)
        vertices.append(v)
        faces.append(f + count)
        count += len(v)
    return LinkGeometry(link, np.vstack(vertices), np.vstack(faces).astype(np.int64), kind)


def _shape_triangles(shape: ET.Element, urdf_path: Path, grid_cells: int) -> tuple[Float64Array, np.ndarray]:
    if shape.tag == "mesh":
        scale = _floats(shape.get("scale", "1 1 1"), 3, "mesh scale")
        path = resolve_mesh_path(shape.get("filename", ""), urdf_path)
        try:
            stat = path.stat()
        except OSError as exc:
            raise _GeometryError(f"{path.name}: {type(exc).__name__}: {exc}") from exc
        return _thinned_mesh(path, stat.st_mtime_ns, stat.st_size, tuple(scale.tolist()), grid_cells)
    if shape.tag == "box":
        return _box(_floats(shape.get("size", ""), 3, "box size"))
    if shape.tag == "cylinder":
        return _cylinder(_floats(shape.get("radius", ""), 1, "radius")[0], _floats(shape.get("length", ""), 1, "length")[0])
    if shape.tag == "sphere":
        return _sphere(_floats(shape.get("radius", ""), 1, "radius")[0])
    raise _GeometryError(f"<{shape.tag}> is not a URDF shape")


def resolve_mesh_path(filename: str, urdf_path: Path) -> Path:
    """The file a URDF mesh `filename` names (package://, file:// or relative to the URDF)."""
    if filename.startswith("file://"):
        return Path(filename[len("file://"):])
    if not filename.startswith("package://"):
        return urdf_path.parent / filename
    package, _, rest = filename[len("package://"):].partition("/")
    ancestors = list(urdf_path.resolve().parents)
    with contextlib.suppress(KinematicsError):  # not installed: the URDF's own folders only
        ancestors.append(example_robot_data_root().parent)
    for folder in ancestors:
        for candidate in (folder / rest if folder.name == package else None, folder / package / rest):
            if candidate is not None and candidate.is_file():
                return candidate
    raise _GeometryError(f"{filename}: no such file in a folder named {package!r} above the URDF, in one beside those, "
                         "or in example-robot-data")


@functools.lru_cache(maxsize=256)
def _thinned_mesh(path: Path, mtime_ns: int, size: int, scale: tuple[float, ...], grid_cells: int) -> tuple[Float64Array, np.ndarray]:
    """A mesh file loaded and thinned once per process (keyed by its stat too, so a file rewritten is read again): each
    camera's pipeline and every robot loaded from one URDF share it. Callers never write to the arrays."""
    del mtime_ns, size  # only part of the key
    return _thin(*_load_mesh(path), np.asarray(scale), grid_cells)


def _load_mesh(path: Path) -> tuple[Float64Array, np.ndarray]:
    try:
        import trimesh  # the `robots` extra; without it no mesh loads and primitives remain
    except ImportError as exc:
        raise _GeometryError("trimesh is not installed (pip install trimesh pycollada, the `robots` extra)") from exc
    try:
        mesh = trimesh.load(str(path), force="mesh", process=False)
        vertices = np.asarray(mesh.vertices, dtype=np.float64)  # type: ignore[attr-defined]
        faces = np.asarray(mesh.faces, dtype=np.int64)  # type: ignore[attr-defined]
    except Exception as exc:  # trimesh and its format readers raise anything from a bad file
        raise _GeometryError(f"{path.name}: {type(exc).__name__}: {exc}") from exc
    if faces.ndim != 2 or len(faces) == 0 or faces.shape[1] != 3 or not np.isfinite(vertices).all():
        raise _GeometryError(f"{path.name}: no triangles")
    return vertices, faces


def _thin(vertices: Float64Array, faces: np.ndarray, scale: Float64Array, grid_cells: int) -> tuple[Float64Array, np.ndarray]:
    """Vertex clustering: vertices in one grid cell merge to their mean; triangles that collapse are dropped."""
    vertices = vertices * scale
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    cell = max(float((high - low).max()) / grid_cells, 1e-9)
    keys = np.floor((vertices - low) / cell).astype(np.int64)
    _, cluster = np.unique(keys, axis=0, return_inverse=True)
    cluster = cluster.reshape(-1)
    count = np.bincount(cluster)
    merged = np.stack([np.bincount(cluster, vertices[:, i]) for i in range(3)], axis=1) / count[:, None]
    tri = cluster[faces]
    keep = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])
    tri = np.unique(np.sort(tri[keep], axis=1), axis=0)
    return merged, tri


def _box(size: Float64Array) -> tuple[Float64Array, np.ndarray]:
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]) * size
    quads = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]
    return corners, np.array([t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int64)


def _cylinder(radius_m: float, length_m: float) -> tuple[Float64Array, np.ndarray]:
    angles = np.arange(CYLINDER_SIDES) * 2 * math.pi / CYLINDER_SIDES
    ring = np.stack([radius_m * np.cos(angles), radius_m * np.sin(angles)], axis=1)
    vertices = np.vstack([np.c_[ring, np.full(CYLINDER_SIDES, -length_m / 2)], np.c_[ring, np.full(CYLINDER_SIDES, length_m / 2)],
                          [[0, 0, -length_m / 2], [0, 0, length_m / 2]]])
    n = CYLINDER_SIDES
    faces = [t for i in range(n) for t in ((i, (i + 1) % n, n + i), ((i + 1) % n, n + (i + 1) % n, n + i),
                                           (2 * n, i, (i + 1) % n), (2 * n + 1, n + i, n + (i + 1) % n))]
    return vertices, np.array(faces, dtype=np.int64)


def _sphere(radius_m: float) -> tuple[Float64Array, np.ndarray]:
    """A UV sphere: SPHERE_RINGS latitude bands of 2 * SPHERE_RINGS quads (poles included as vertex rings)."""
    lat = np.linspace(0, math.pi, SPHERE_RINGS + 1)
    lon = np.arange(2 * SPHERE_RINGS) * math.pi / SPHERE_RINGS
    vertices = radius_m * np.array([[math.sin(a) * math.cos(b), math.sin(a) * math.sin(b), math.cos(a)] for a in lat for b in lon])
    m = len(lon)
    faces = [
        t
        for i in range(SPHERE_RINGS)
        for j in range(m)
        for t in ((i * m + j, i * m + (j + 1) % m, (i + 1) * m + j), (i * m + (j + 1) % m, (i + 1) * m + (j + 1) % m, (i + 1) * m + j))
    ]
    return vertices, np.array(faces, dtype=np.int64)


def _origin(el: ET.Element | None) -> Transform:
    if el is None:
        return Transform.identity()
    x, y, z = _floats(el.get("xyz", "0 0 0"), 3, "origin xyz")
    roll, pitch, yaw = _floats(el.get("rpy", "0 0 0"), 3, "origin rpy")
    cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    rotation = np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                         [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                         [-sp, cp * sr, cp * cr]])
    return Transform(rotation, np.array([x, y, z]))


def _floats(text: str, count: int, what: str) -> Float64Array:
    try:
        values = np.array([float(v) for v in text.split()], dtype=np.float64)
    except ValueError as exc:
        raise _GeometryError(f"{what} {text!r}: expected {count} numbers") from exc
    if len(values) != count or not np.isfinite(values).all():
        raise _GeometryError(f"{what} {text!r}: expected {count} finite numbers")
    return values
