"""The robots drawn from their URDF meshes, every pixel labelled with its link: the truth visibility is tested against.

The rasteriser is the visibility render's (engine/visibility.py), run at every
pixel and with meshes thinned on a finer grid than the node's, so the node's
thinning and sampling are part of what a test against it measures. Each
pixel keeps the nearest link's label (`MeshFrame.link_mask`), and each arm's
gripper silhouette is kept whatever lies in front, so a frame knows how much
of every gripper it shows. The capsule painter (sim/painter.py) stays what
`roi-node sim` draws by default (`--draw meshes` draws this), so simulated bags
keep their bytes.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

from roi_node.engine.camera import CameraModel
from roi_node.engine.config import RigConfig
from roi_node.engine.kinematics import RobotKinematics
from roi_node.engine.transforms import Transform
from roi_node.engine.visibility import VisibilityModel


class Drawing(StrEnum):
    """How the simulator draws the robots."""

    CAPSULES = "capsules"  # capsule chains and a generic gripper (sim/painter.py): what simulated bags were recorded with
    MESHES = "meshes"  # the URDF's meshes, every pixel labelled with its link (this module)


MESH_GRID_CELLS = 48  # cells along a mesh's longest side: four times the node's grid
LINK_GREY = 200.0
GRIPPER_RGB = (60.0, 62.0, 70.0)


@dataclass(frozen=True)
class MeshFrame:
    """One drawn frame: the nearest link per pixel (-1: none) and each arm's gripper silhouette."""

    labels: np.ndarray  # H x W int64, indices into link_names
    link_names: tuple[str, ...]  # `<robot id>/<link>`
    gripper_covered: Mapping[str, np.ndarray]  # arm id -> H x W bool
    gripper_links: Mapping[str, frozenset[int]]  # arm id -> its gripper's labels

    def link_mask(self, link: str) -> np.ndarray:
        """Where `<robot id>/<link>` is the nearest surface."""
        return self.labels == self.link_names.index(link)

    def visible_fraction(self, arm_id: str, window: tuple[int, int, int, int]) -> tuple[float | None, int]:
        """(visible share of the arm's gripper inside `window` (x0, y0, x1 exclusive, y1), its silhouette in px)."""
        x0, y0 = max(window[0], 0), max(window[1], 0)
        x1, y1 = min(window[2], self.labels.shape[1]), min(window[3], self.labels.shape[0])
        if x1 <= x0 or y1 <= y0:
            return None, 0
        covered = self.gripper_covered[arm_id][y0:y1, x0:x1]
        silhouette = int(covered.sum())
        if silhouette == 0:
            return None, 0
        visible = np.isin(self.labels[y0:y1, x0:x1][covered], list(self.gripper_links[arm_id]))
        return float(visible.sum() / silhouette), silhouette

    def hiding_link(self, arm_id: str, window: tuple[int, int, int, int]) -> tuple[str | None, float]:
        """The link nearest in front of most of the gripper's hidden pixels in `window`, and its share of the silhouette."""
        x0, y0 = max(window[0], 0), max(window[1], 0)
        x1, y1 = min(window[2], self.labels.shape[1]), min(window[3], self.labels.shape[0])
        covered = self.gripper_covered[arm_id][y0:y1, x0:x1]
        front = self.labels[y0:y1, x0:x1][covered]
        hidden = front[~np.isin(front, list(self.gripper_links[arm_id]))]
        if len(hidden) == 0:
            return None, 0.0
        counts = np.bincount(hidden)
        return self.link_names[int(counts.argmax())], float(counts.max() / len(front))

    def paint(self, background: np.ndarray) -> np.ndarray:
        """The background with every link in its own light grey (neighbours tell apart) and every gripper dark."""
        colours = np.repeat(LINK_GREY - (np.arange(len(self.link_names), dtype=np.float64) * 37.0) % 60.0, 3).reshape(-1, 3)
        for labels in self.gripper_links.values():
            colours[list(labels)] = GRIPPER_RGB
        frame = background.copy()
        drawn = self.labels >= 0
        frame[drawn] = colours[self.labels[drawn]].astype(np.uint8)
        return frame


class MeshPainter:
    """Draws a rig's robots through its (fixed) camera at a frame's joint positions (JointState names)."""

    def __init__(self, rig: RigConfig, camera: CameraModel, grid_cells: int = MESH_GRID_CELLS) -> None:
        kinematics = {r.id: RobotKinematics(r.id, r.urdf_path) for r in rig.robots}
        self.model = VisibilityModel(rig, kinematics, grid_cells)
        self.camera = camera
        self.z_min_m = rig.camera.z_min_m
        cam_T_world = rig.camera.world_T_cam.inverse()
        self.cam_T_bases: dict[str, Transform | None] = {r.id: cam_T_world @ r.world_T_base for r in rig.robots}
        self.arm_ids = tuple(a.id for a in rig.arms)

    def draw(self, positions: Mapping[str, float]) -> MeshFrame | None:
        """The whole frame; None when the robots cannot be drawn (a mesh that did not load, geometry behind the camera)."""
        window = (0, 0, self.camera.width_px, self.camera.height_px)
        drawn = self.model.render(self.camera, self.z_min_m, self.cam_T_bases, positions, window)
        if drawn is None:
            return None
        labels, covered = drawn
        grippers = {arm_id: frozenset(self.model.gripper_labels(i)) for i, arm_id in enumerate(self.arm_ids)}
        return MeshFrame(labels, self.model.link_names, dict(zip(self.arm_ids, covered, strict=True)), grippers)
