"""Differential IK for the FR3 with mink: the end-effector target to an arm joint command.

Built once per session (tasks and limits on the scene's kinematic model), solved once per
control tick::

    target (p, q) --FrameTask(attachment_site) + PostureTask--> QP (daqp)
        s.t. ConfigurationLimit, VelocityLimit, CollisionAvoidanceLimit(arm + tool vs table)
        --> v --integrate dt--> q_cmd (7,)

The controller keeps its own configuration (the commanded joint angles); the simulated robot
follows it through its position actuators. When the QP has no solution or returns garbage the
command stays at the last good one and :class:`IkResult` carries a warning.
"""

# mujoco ships compiled bindings without type stubs, so pyright cannot see MjModel, mj_step,
# mjtObj, ...: attribute checks on the mujoco module are off in this file.
# pyright: reportAttributeAccessIssue=false

from __future__ import annotations

import math
from dataclasses import dataclass

import mink
import mujoco
import numpy as np

from bt_pipeline.data.records import FloatArray
from bt_pipeline.exceptions import ConfigError
from bt_teleop.sim.scene import ARM_JOINTS, EE_SITE, HOME_KEY, TABLE_GEOM, SceneModel

FR3_MAX_JOINT_VELOCITY: tuple[float, ...] = (2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26)
"""Joint velocity limits of the FR3 [rad/s] (Franka's FR3 datasheet)."""


class _TableAvoidanceLimit(mink.CollisionAvoidanceLimit):
    """mink's collision avoidance with its bound in the units of the QP variable.

    The QP of ``mink.solve_ik`` is in the displacement Δq = v·dt, and the configuration and
    velocity limits bound Δq; mink 1.3's collision limit bounds the approach by
    gain·(d - d_min)/dt, a velocity. At dt = 0.01 s that lets a geom close 100 times the gap
    in one tick, so a tool could cross the table top in a tick or two. Evaluating it with dt = 1
    bounds the approach per tick by gain·(d - d_min), as the limit intends.
    """

    def compute_qp_inequalities(self, configuration: mink.Configuration, dt: float):
        del dt  # the bound is a displacement; see the class docstring
        return super().compute_qp_inequalities(configuration, 1.0)


@dataclass(frozen=True)
class IkSettings:
    """Weights and limits of the IK problem."""

    solver: str = "daqp"
    """QP solver (``daqp`` is the one mink's dependencies install)."""
    position_cost: float = 1.0
    """FrameTask position weight [1/m]."""
    orientation_cost: float = 0.5
    """FrameTask orientation weight [1/rad]."""
    posture_cost: float = 1e-2
    """PostureTask weight: pulls the null space towards the session's ready posture."""
    lm_damping: float = 1e-3
    """Levenberg-Marquardt damping of the frame task (robust near singularities)."""
    velocity_scale: float = 1.0
    """Fraction of :data:`FR3_MAX_JOINT_VELOCITY` the command may use, in (0, 1]."""
    table_distance_m: float = 0.005
    """Smallest distance kept between the arm/tool and the table [m]."""
    detection_distance_m: float = 0.05
    """Distance at which table avoidance becomes active [m]."""

    def __post_init__(self) -> None:
        if not 0.0 < self.velocity_scale <= 1.0:
            raise ConfigError(f"velocity_scale must be in (0, 1]; got {self.velocity_scale}")
        for name in ("position_cost", "orientation_cost", "posture_cost", "lm_damping"):
            if not getattr(self, name) >= 0.0:
                raise ConfigError(f"{name} must be >= 0; got {getattr(self, name)}")


@dataclass(frozen=True, eq=False)  # holds arrays: compare fields explicitly
class IkResult:
    """The outcome of one IK tick."""

    q_arm: FloatArray
    """Arm joint command fr3_joint1..7, shape (7,), in [rad] (the last good one on failure)."""
    v_arm: FloatArray
    """Arm joint velocity of this step, shape (7,), in [rad/s] (0 on failure)."""
    ok: bool
    """Whether this tick's QP was solved."""
    warning: str | None = None
    """Why the tick failed, None when it succeeded."""


class IkController:
    """mink IK on a scene's kinematic model, keeping the commanded configuration."""

    def __init__(self, scene: SceneModel, dt_s: float, settings: IkSettings | None = None) -> None:
        """Build tasks and limits and start at the keyframe ``home``.

        Args:
            scene: The scene (its :attr:`~SceneModel.ik_model` is used).
            dt_s: Control period, the IK integration step [s].
            settings: Weights and limits; defaults when None.
        """
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ConfigError(f"IK step dt_s must be a positive number of seconds; got {dt_s}")
        self.settings = settings or IkSettings()
        self.dt_s = float(dt_s)
        model = scene.ik_model
        self._model = model
        self._arm_adr = np.array(scene.ik_arm_qpos_adr)
        self._arm_dof = np.array(
            [model.jnt_dofadr[model.joint(name).id] for name in ARM_JOINTS], dtype=int
        )
        self.configuration = mink.Configuration(model)
        self.configuration.update_from_keyframe(HOME_KEY)  # qpos0 breaks the FR3's joint limits
        s = self.settings
        self._frame_task = mink.FrameTask(
            EE_SITE,
            "site",
            position_cost=s.position_cost,
            orientation_cost=s.orientation_cost,
            lm_damping=s.lm_damping,
        )
        self._posture_task = mink.PostureTask(model, cost=s.posture_cost)
        self._posture_task.set_target_from_configuration(self.configuration)
        self._tasks = [self._frame_task, self._posture_task]
        velocities = {
            joint: s.velocity_scale * v
            for joint, v in zip(ARM_JOINTS, FR3_MAX_JOINT_VELOCITY, strict=True)
        }
        self._limits: list[mink.Limit] = [
            mink.ConfigurationLimit(model),
            mink.VelocityLimit(model, velocities),
            _TableAvoidanceLimit(
                model,
                geom_pairs=[(list(scene.avoid_geoms), [TABLE_GEOM])],
                minimum_distance_from_collisions=s.table_distance_m,
                collision_detection_distance=s.detection_distance_m,
            ),
        ]
        self._site_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, EE_SITE)

    @property
    def q_arm(self) -> FloatArray:
        """The current arm joint command, shape (7,) [rad] (a copy)."""
        return self.configuration.q[self._arm_adr].copy()

    def reset(self, q_arm: FloatArray | None = None) -> None:
        """Return to the keyframe ``home``, then set the arm to `q_arm` (7,) [rad] if given."""
        self.configuration.update_from_keyframe(HOME_KEY)
        if q_arm is not None:
            q = self.configuration.q.copy()
            q[self._arm_adr] = q_arm
            self.configuration.update(q)

    def hold_posture(self) -> None:
        """Make the current configuration the posture the null space is pulled to."""
        self._posture_task.set_target_from_configuration(self.configuration)

    def ee_pose(self) -> tuple[FloatArray, FloatArray]:
        """Position (3,) [m] and orientation wxyz (4,) of the end effector at the command."""
        data = self.configuration.data
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, data.site_xmat[self._site_id])
        return data.site_xpos[self._site_id].copy(), quat

    def solve(self, pos: FloatArray, quat: FloatArray, dt_s: float | None = None) -> IkResult:
        """One IK step towards the target; the command moves only when the QP is solved.

        Args:
            pos: Target position of attachment_site, shape (3,), in [m] (world frame).
            quat: Target orientation wxyz, shape (4,), unit norm.
            dt_s: Integration step [s]; the control period when None.

        Returns:
            The new command, or the last good one with a warning.
        """
        dt = self.dt_s if dt_s is None else dt_s
        target = mink.SE3.from_rotation_and_translation(
            mink.SO3(wxyz=np.asarray(quat, dtype=np.float64)), np.asarray(pos, dtype=np.float64)
        )
        self._frame_task.set_target(target)
        try:
            velocity = mink.solve_ik(
                self.configuration,
                self._tasks,
                dt,
                self.settings.solver,
                limits=self._limits,
            )
        except (mink.NoSolutionFound, ValueError, np.linalg.LinAlgError) as exc:
            return self._failed(f"IK failed ({exc}); holding the pose")
        if not np.all(np.isfinite(velocity)):
            return self._failed("IK returned NaN; holding the pose")
        self.configuration.integrate_inplace(velocity, dt)
        return IkResult(self.q_arm, velocity[self._arm_dof].copy(), ok=True)

    def _failed(self, warning: str) -> IkResult:
        return IkResult(self.q_arm, np.zeros(len(self._arm_dof)), ok=False, warning=warning)

    def converge(
        self,
        pos: FloatArray,
        quat: FloatArray,
        *,
        max_iterations: int = 400,
        tol_m: float = 1e-4,
        tol_rad: float = 1e-3,
    ) -> IkResult:
        """Iterate the IK (with a long step) until the target is reached, e.g. for a start pose.

        Returns:
            The converged command; ``ok`` is False with a warning when the tolerance was not met.
        """
        result = IkResult(self.q_arm, np.zeros(len(self._arm_dof)), ok=True)
        posture_target = self._posture_task.target_q
        for _ in range(max_iterations):
            # Posture as pure regularisation (target = current q), so it does not bias the result.
            self._posture_task.set_target_from_configuration(self.configuration)
            result = self.solve(pos, quat, dt_s=0.05)
            error = self._frame_task.compute_error(self.configuration)
            if np.linalg.norm(error[:3]) < tol_m and np.linalg.norm(error[3:]) < tol_rad:
                break
        else:
            result = self._failed(
                f"IK did not reach {np.round(pos, 3).tolist()} in {max_iterations} steps"
            )
        if posture_target is not None:
            self._posture_task.set_target(posture_target)
        return result
