"""What one tab's 3-D view shows: lighting, the robot, the target gizmo and marker, the floor,
the task-shape guide, the live trail and replayed paths, drawn into the tab's own ``client.scene``.

::

    TabScene(scene_api, task scene, on_drag)   lighting, robot, gizmo, marker, floor, trail
    show_task(task scene)                      a task switch: redraw robot, gizmo, marker, floor
    frame(camera, task scene)                  the task's default camera (and "Reset view")
    draw_guide(task scene, θ, ρ)               the blue loop the demonstrator traces
    show(status, trail)                        one frame (inside the tab's ``client.atomic()``)
    draw_replay_path / clear_replay_paths      cleaned (green, solid, on top) and raw (light
                                               orange, wide, dashed, beneath) paths: both
                                               show where they overlap

Only the tab worker (:class:`bt_teleop.ui.tab.ClientUI`) calls it; the gizmo callback only hands
the dragged position to ``on_drag``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import viser

from bt_pipeline.data.records import FloatArray
from bt_teleop.library.listing import TrackKind
from bt_teleop.session.config import SessionStatus
from bt_teleop.sim.scene import SceneModel
from bt_teleop.ui.framing import default_view, plane_wxyz
from bt_teleop.ui.viewer import MjSceneView, Trail, draw_path, floor_height, guide_loop_world

__all__ = [
    "CLEANED_RGB",
    "GIZMO_SCALE_M",
    "GUIDE_RGB",
    "RAW_RGB",
    "TRAIL_RGB",
    "Frame",
    "TabScene",
]

RAW_RGB = (255, 175, 70)
"""Colour of a replayed raw demo's path."""
CLEANED_RGB = (40, 200, 110)
"""Colour of a replayed cleaned demo's path."""
TRAIL_RGB = (220, 40, 60)
"""Colour of the live end-effector trail while recording."""
GUIDE_RGB = (70, 130, 255)
"""Colour of the task-shape guide."""
REPLAY_NODES = ("/replay/raw", "/replay/cleaned")
"""Scene nodes of the replayed paths."""
GIZMO_SCALE_M = 0.3
"""Length of the gizmo's arrows [m] (its squares are 0.225 of it across): their tips and the
square between u and v reach past the tool and the arm (bt_teleop/ui/framing.py)."""
GIZMO_LINE_WIDTH_PX = 4.0
"""Width of the gizmo's lines [px]."""
RAW_THICKNESS_M = 0.008
"""Width of a replayed raw path [m] (dashed): twice the cleaned one's, so it shows on both
sides of a cleaned path drawn over it."""
CLEANED_THICKNESS_M = 0.004
"""Width of a replayed cleaned path [m]."""
CLEANED_LIFT_M = 0.0015
"""The cleaned path is drawn this far [m] off its samples toward the side of the task plane the
default camera looks from, so it lies on top of its raw source where the two coincide (cleaning
moves a demo by a few mm at most; both at one depth would each hide the other in patches)."""


@dataclass(frozen=True)
class Frame:
    """The last scene update sent to the tab."""

    index: int
    """Updates sent so far."""
    wall_time_s: float
    """``time.perf_counter()`` when it was queued [s]."""
    sim_time_s: float
    """Simulation time of the pose sent [s]."""
    ee_pos: FloatArray
    """End-effector position sent, shape (3,) [m]."""


class TabScene:
    """The 3-D scene of one tab."""

    def __init__(
        self,
        scene_api: viser.SceneApi,
        scene: SceneModel,
        on_drag: Callable[[FloatArray], None],
        *,
        fancy_lighting: bool = False,
    ) -> None:
        """Draw `scene` (and plain lighting unless `fancy_lighting`).

        Args:
            scene_api: The tab's own ``client.scene``.
            scene: The tab's task scene.
            on_drag: Called with the gizmo's position (3,) [m] on every drag update.
            fancy_lighting: Keep viser's environment map and shadows.
        """
        self.scene_api = scene_api
        self._on_drag = on_drag
        if not fancy_lighting:
            plain_lighting(scene_api)
        self.view = MjSceneView(scene_api, scene.model, root="/robot")
        self._draw_task(scene)
        self.trail = Trail(scene_api, "/trail", TRAIL_RGB)

    def show_task(self, scene: SceneModel) -> None:
        """Redraw for a new task: its robot, gizmo, target marker and floor; no trail."""
        self.view.remove()
        self.view = MjSceneView(self.scene_api, scene.model, root="/robot")
        self.trail.clear()
        self._draw_task(scene)

    def draw_guide(self, scene: SceneModel, theta_deg: float, rho: float) -> None:
        """Draw the task's shape under θ [deg] and ρ on its plane."""
        loop = guide_loop_world(scene, theta_deg, rho)
        draw_path(self.scene_api, "/guide", loop, GUIDE_RGB, closed=True, thickness=0.003)

    def show(self, status: SessionStatus, trail: FloatArray | None, *, follow: bool) -> None:
        """One frame: robot pose, target marker, the trail (None: unchanged) and, when
        `follow` (a replay drives the robot), the gizmo at the commanded position."""
        self.view.update(status.qpos)
        self.target_marker.position = status.target_pos
        self.target_marker.color = (255, 60, 60) if status.target_clamped else (255, 200, 0)
        if trail is not None:
            self.trail.set(trail)
        if follow:
            self.gizmo.position = status.command_pos

    def draw_replay_path(self, kind: TrackKind, positions: FloatArray) -> None:
        """Draw a replayed demo's path, shape (T, 3) [m] (a cleaned one beside its raw source):
        cleaned solid, green, narrow and on top (:data:`CLEANED_LIFT_M`); raw dashed, light
        orange and twice as wide, so where a cleaned path follows its raw one the raw shows on
        both sides of it, and where they part each shows whole."""
        cleaned = kind == "cleaned"
        draw_path(
            self.scene_api,
            f"/replay/{kind}",
            positions + CLEANED_LIFT_M * self._toward_camera if cleaned else positions,
            CLEANED_RGB if cleaned else RAW_RGB,
            thickness=CLEANED_THICKNESS_M if cleaned else RAW_THICKNESS_M,
            dashed=not cleaned,
        )

    def clear_replay_paths(self) -> None:
        """Remove the replayed paths."""
        for name in REPLAY_NODES:
            handle = self.scene_api.get_handle_by_name(name)
            if handle is not None:
                handle.remove()

    @staticmethod
    def frame(camera: viser.CameraHandle, scene: SceneModel) -> None:
        """Point a tab's `camera` at `scene`'s task plane, guide and trail (:mod:`framing`)."""
        view = default_view(scene.plane)
        camera.up_direction = tuple(view.up)
        camera.position = tuple(view.position)
        camera.look_at = tuple(view.look_at)
        camera.fov = view.fov_rad

    def _draw_task(self, scene: SceneModel) -> None:
        """(Re)draw what depends on the task: gizmo, target marker, floor."""
        normal = scene.plane.normal / np.linalg.norm(scene.plane.normal)
        seen_from = default_view(scene.plane).position - scene.plane.origin
        self._toward_camera = normal if float(normal @ seen_from) > 0.0 else -normal
        """Unit normal of the task plane on the default camera's side, shape (3,)."""
        self.gizmo = self.scene_api.add_transform_controls(
            "/target",
            scale=GIZMO_SCALE_M,
            line_width=GIZMO_LINE_WIDTH_PX,
            disable_rotations=True,
            depth_test=False,  # drawn over the robot: it sits inside the tool
            position=scene.ready_pos,
            wxyz=plane_wxyz(scene.plane),  # arrows along the task plane's axes u, v, normal
        )

        @self.gizmo.on_update
        async def _(event: viser.TransformControlsEvent) -> None:
            self._on_drag(event.target.position)

        self.target_marker = self.scene_api.add_icosphere(
            "/target_marker", radius=0.008, color=(255, 200, 0), position=scene.ready_pos
        )
        floor_z = floor_height(scene.model)
        if floor_z is not None:
            self.scene_api.add_grid("/floor", width=4.0, height=4.0, position=(0.0, 0.0, floor_z))


def plain_lighting(scene_api: viser.SceneApi) -> None:
    """Cheap lighting: no environment map, no shadows; sky, ambient and a key light."""
    scene_api.configure_environment_map(None)
    scene_api.configure_default_lights(enabled=False, cast_shadow=False)
    scene_api.add_light_hemisphere(
        "/lights/sky", sky_color=(255, 255, 255), ground_color=(90, 90, 100), intensity=1.2
    )
    scene_api.add_light_ambient("/lights/ambient", intensity=0.6)
    scene_api.add_light_directional(
        "/lights/key", intensity=1.6, position=(1.5, -1.0, 2.5), cast_shadow=False
    )
