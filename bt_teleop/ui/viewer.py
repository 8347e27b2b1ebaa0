"""Drawing a MuJoCo scene, paths and the task guide into one browser tab's viser scene.

Every tab has its own robot, so everything here draws into the ``SceneApi`` it is given (a
client's ``client.scene``, never the shared ``server.scene``). The model is drawn once as meshes
(primitives through trimesh, mesh geoms from the model's own vertices), grouped per body and
colour; afterwards only the pose of each moving body's frame is sent::

    MjSceneView(scene_api, model)           once: /<root>/static/* (world-welded geoms)
                                                  /<root>/body_<b> frames + geometry children
    view.update(qpos)  (publisher thread)   mj_kinematics on a private MjData
                                            -> position / wxyz of each moving body's frame
                                               (viser drops updates that change nothing)

Only geom groups 0-2 are drawn (MuJoCo's default viewer groups); collision proxies (group 3)
and IK guards (group 5) are not. Textures are ignored: a geom takes its material's colour.
"""

# mujoco ships compiled bindings without type stubs, so pyright cannot see MjModel, mj_step,
# mjtObj, ...: attribute checks on the mujoco module are off in this file.
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

from collections.abc import Sequence

import mujoco
import numpy as np
import trimesh
import viser
from numpy.typing import ArrayLike

from bt_pipeline.data.records import FloatArray
from bt_pipeline.data.shapes import canonical_loop, similarity_transform
from bt_teleop.sim.scene import SceneModel

VISIBLE_GROUPS = (0, 1, 2)
"""Geom groups drawn (MuJoCo's default visible groups)."""
Rgb = tuple[int, int, int]

_GEOM = mujoco.mjtGeom
# Tessellation of round primitives: ~500 triangles a capsule (trimesh's default is 4096), so
# the FR3 stays light for software WebGL (headless browsers, laptops without a GPU).
_CAPSULE_COUNT = (24, 12)
_SECTIONS = 24


class MjSceneView:
    """A MuJoCo model drawn into one viser scene, moved by qpos updates."""

    def __init__(self, scene_api: viser.SceneApi, model: mujoco.MjModel, root: str = "/mj"):
        """Draw `model` at its qpos0 under the node `root` of `scene_api`."""
        self.root = root
        self.model = model
        self._data = mujoco.MjData(model)
        self._api = scene_api
        self._frames: dict[int, viser.SceneNodeHandle] = {}
        self._nodes: list[viser.SceneNodeHandle] = []
        mujoco.mj_kinematics(model, self._data)
        groups = _merged_geoms(model)
        moving = sorted({body for body, *_ in groups if int(model.body_weldid[body]) != 0})
        for body in moving:
            self._frames[body] = scene_api.add_frame(f"{root}/body_{body}", show_axes=False)
        for k, (body, color, opacity, mesh) in enumerate(groups):
            static = int(model.body_weldid[body]) == 0
            if static:  # geometry already in world coordinates
                mesh = mesh.copy()
                mesh.apply_transform(_pose_matrix(self._data.xpos[body], self._data.xquat[body]))
            parent = f"{root}/static" if static else f"{root}/body_{body}"
            self._nodes.append(
                scene_api.add_mesh_simple(
                    f"{parent}/mesh_{k}",
                    np.asarray(mesh.vertices, dtype=np.float32),
                    np.asarray(mesh.faces, dtype=np.uint32),
                    color=color,
                    opacity=opacity,
                    flat_shading=False,
                )
            )
        self.update(self._data.qpos)

    @property
    def moving_bodies(self) -> tuple[int, ...]:
        """Ids of the bodies whose frames are updated."""
        return tuple(self._frames)

    def update(self, qpos: ArrayLike) -> None:
        """Move the drawn bodies to the configuration `qpos`, shape (nq,)."""
        self._data.qpos[:] = np.asarray(qpos, dtype=np.float64)
        mujoco.mj_kinematics(self.model, self._data)
        for body, frame in self._frames.items():
            frame.position = self._data.xpos[body]
            frame.wxyz = self._data.xquat[body]

    def set_visible(self, visible: bool, *, moving_only: bool = True) -> None:
        """Show or hide the drawn model (only the moving bodies, e.g. the robot, by default)."""
        for node in (
            self._frames.values() if moving_only else [*self._frames.values(), *self._nodes]
        ):
            node.visible = visible

    def body_pose(self, body: int) -> tuple[FloatArray, FloatArray]:
        """Last drawn position (3,) [m] and orientation wxyz (4,) of `body`."""
        return self._data.xpos[body].copy(), self._data.xquat[body].copy()

    def remove(self) -> None:
        """Remove everything this view drew."""
        for node in [*self._nodes, *self._frames.values()]:
            node.remove()
        self._nodes.clear()
        self._frames.clear()


class Trail:
    """A growing polyline drawn in chunks: only the newest chunk is re-sent as it grows."""

    def __init__(
        self,
        scene_api: viser.SceneApi,
        name: str,
        color: Rgb,
        chunk: int = 128,
        thickness: float = 0.004,
    ) -> None:
        """Prepare an empty trail drawn under node `name` in `color`, `chunk` segments a node."""
        self.name = name
        self.color = color
        self.chunk = chunk
        self.thickness = thickness
        self._api = scene_api
        self._handles: list[viser.SceneNodeHandle] = []
        self._complete = 0  # leading chunks that are full and never re-sent
        self._n = 0  # points drawn

    def set(self, points: ArrayLike) -> None:
        """Draw `points`, shape (T, 3) [m]; a shorter polyline than the last one starts over."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        n = int(p.shape[0])
        if n < self._n:
            self.clear()
        needed = 0 if n < 2 else -(-(n - 1) // self.chunk)
        for k in range(self._complete, needed):
            start = k * self.chunk
            stop = min(n, start + self.chunk + 1)  # chunks share their end points
            node = self._api.add_line_segments(  # same name: replaces the node
                f"{self.name}/chunk_{k}",
                segments(p[start:stop]),
                self.color,
                thickness=self.thickness,
                thickness_units="world",
            )
            if k < len(self._handles):
                self._handles[k] = node
            else:
                self._handles.append(node)
            if stop == start + self.chunk + 1:
                self._complete = k + 1
        self._n = n

    def clear(self) -> None:
        """Remove every chunk."""
        for handle in self._handles:
            handle.remove()
        self._handles.clear()
        self._complete = 0
        self._n = 0

    @property
    def n_chunks(self) -> int:
        """Chunk nodes drawn."""
        return len(self._handles)


def segments(points: ArrayLike, closed: bool = False) -> FloatArray:
    """Consecutive pairs of a polyline, shape (T - 1, 2, 3) (T with `closed`), from (T, 3)."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    q = np.vstack([p, p[:1]]) if closed and len(p) > 2 else p
    return np.stack([q[:-1], q[1:]], axis=1)


def dashed_segments(points: ArrayLike, dash_m: float = 0.01, gap_m: float = 0.006) -> FloatArray:
    """The segments of a polyline (T, 3) [m] that fall in its dashes, shape (K, 2, 3).

    Along the path's arc length, `dash_m` [m] drawn then `gap_m` [m] left out, in turn; a
    segment is kept when its midpoint lies in a dash (demo samples are a few mm apart, so the
    dashes come out about `dash_m` long).
    """
    pairs = segments(points)
    if len(pairs) == 0:
        return pairs
    lengths = np.linalg.norm(pairs[:, 1] - pairs[:, 0], axis=1)
    middle = np.cumsum(lengths) - 0.5 * lengths
    return pairs[np.mod(middle, dash_m + gap_m) < dash_m]


def draw_path(
    scene_api: viser.SceneApi,
    name: str,
    points: ArrayLike,
    color: Rgb,
    *,
    closed: bool = False,
    thickness: float = 0.004,
    dashed: bool = False,
) -> viser.SceneNodeHandle:
    """Draw a polyline (T, 3) [m] as line segments (replaces a node of the same name), solid
    or `dashed` (:func:`dashed_segments`)."""
    pairs = dashed_segments(points) if dashed else segments(points, closed=closed)
    return scene_api.add_line_segments(
        name,
        pairs,
        color,
        thickness=thickness,
        thickness_units="world",
    )


def guide_loop_world(scene: SceneModel, theta_deg: float, rho: float, n: int = 200) -> FloatArray:
    """The task's canonical shape under the preference (θ [deg], ρ) on the task plane, (n, 3) [m].

    The shape (centred at the task-plane origin) is rotated by θ and scaled by ρ
    (:func:`bt_pipeline.data.shapes.similarity_transform`), then mapped to the world.
    """
    loop = similarity_transform(canonical_loop(scene.task, n), theta_deg, rho)
    return scene.plane.to_world(loop)


def _merged_geoms(model: mujoco.MjModel) -> list[tuple[int, Rgb, float | None, trimesh.Trimesh]]:
    """Visible geoms merged per (body, colour, opacity), in the body frame."""
    parts: dict[tuple[int, Rgb, float | None], list[trimesh.Trimesh]] = {}
    for g in range(model.ngeom):
        if int(model.geom_group[g]) not in VISIBLE_GROUPS:
            continue
        rgba = _geom_rgba(model, g)
        if rgba[3] <= 0.0:
            continue
        mesh = _geom_mesh(model, g)
        if mesh is None:
            continue
        mesh.apply_transform(_pose_matrix(model.geom_pos[g], model.geom_quat[g]))
        color: Rgb = (int(255 * rgba[0]), int(255 * rgba[1]), int(255 * rgba[2]))
        opacity = None if rgba[3] >= 1.0 else round(float(rgba[3]), 3)
        parts.setdefault((int(model.geom_bodyid[g]), color, opacity), []).append(mesh)
    merged = []
    for (body, color, opacity), meshes in parts.items():
        mesh = meshes[0] if len(meshes) == 1 else trimesh.util.concatenate(meshes)
        assert isinstance(mesh, trimesh.Trimesh)
        merged.append((body, color, opacity, mesh))
    return merged


def _geom_rgba(model: mujoco.MjModel, g: int) -> FloatArray:
    mat = int(model.geom_matid[g])
    return np.array(model.mat_rgba[mat] if mat >= 0 else model.geom_rgba[g], dtype=np.float64)


def _geom_mesh(model: mujoco.MjModel, g: int) -> trimesh.Trimesh | None:
    """The geom's surface in its own frame, or None for types not drawn (planes, height fields)."""
    kind = int(model.geom_type[g])
    size = model.geom_size[g]
    if kind == _GEOM.mjGEOM_BOX:
        return trimesh.creation.box(extents=2.0 * size)
    if kind == _GEOM.mjGEOM_SPHERE:
        return trimesh.creation.icosphere(subdivisions=2, radius=float(size[0]))
    if kind == _GEOM.mjGEOM_CAPSULE:
        return trimesh.creation.capsule(
            height=2.0 * float(size[1]), radius=float(size[0]), count=_CAPSULE_COUNT
        )
    if kind == _GEOM.mjGEOM_CYLINDER:
        return trimesh.creation.cylinder(
            radius=float(size[0]), height=2.0 * float(size[1]), sections=_SECTIONS
        )
    if kind == _GEOM.mjGEOM_ELLIPSOID:
        sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
        sphere.apply_scale(size)
        return sphere
    if kind == _GEOM.mjGEOM_MESH:
        mesh_id = int(model.geom_dataid[g])
        v0, nv = int(model.mesh_vertadr[mesh_id]), int(model.mesh_vertnum[mesh_id])
        f0, nf = int(model.mesh_faceadr[mesh_id]), int(model.mesh_facenum[mesh_id])
        return trimesh.Trimesh(
            vertices=np.array(model.mesh_vert[v0 : v0 + nv]),
            faces=np.array(model.mesh_face[f0 : f0 + nf]),
            process=False,
        )
    return None


def _pose_matrix(pos: ArrayLike, quat_wxyz: ArrayLike) -> FloatArray:
    """4×4 homogeneous transform from a position (3,) and a unit quaternion wxyz (4,)."""
    rot = np.empty(9)
    mujoco.mju_quat2Mat(rot, np.asarray(quat_wxyz, dtype=np.float64))
    out = np.eye(4)
    out[:3, :3] = rot.reshape(3, 3)
    out[:3, 3] = np.asarray(pos, dtype=np.float64)
    return out


def floor_height(model: mujoco.MjModel) -> float | None:
    """z of the first plane geom of the world body [m] (the floor), None without one."""
    for g in range(model.ngeom):
        if int(model.geom_type[g]) == _GEOM.mjGEOM_PLANE and int(model.geom_bodyid[g]) == 0:
            return float(model.geom_pos[g][2])
    return None


__all__: Sequence[str] = [
    "MjSceneView",
    "Trail",
    "dashed_segments",
    "draw_path",
    "floor_height",
    "guide_loop_world",
    "segments",
]
