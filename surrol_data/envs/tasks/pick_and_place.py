"""PickAndPlace: put every coloured jack into the tray of its colour (the paper's new training task).

"The trainee needs to pick up the colored jacks and place them in the tray in the same color. The task will be
considered as success only when all the colored jacks are placed on the corresponding trays." One jack per
tray colour lies on the table; the trays' places are drawn per episode.

Goals report every jack, so HER can relabel any of them: the achieved goal is the jacks' centres (3 per jack,
in colour order), the desired goal the centre each jack would have lying in its tray. A jack counts as in its
tray when its centre is inside the tray's walls (x and y within the inner half-width of the tray centre) and at
most 3 mm above where it would rest on the floor: let go, not held above it. Reward −1 until every jack is in.

Observation (25): the tip's 7 terms; the "active" jack's centre, centre − tip, centre again (a jack has no
waypoint link) and Euler angles — the active jack is the first, in colour order, not yet in its tray; then
every jack's centre.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from surrol_data.envs import jacks, objects
from surrol_data.envs import kinematics as kin
from surrol_data.envs import physics
from surrol_data.envs.numeric import all_last
from surrol_data.envs.psm_env import WORKSPACE, PsmEnv, tip_clip_box, wrap_angle

OPEN, CLOSE = 0.5, -0.5


class PickAndPlace(PsmEnv):
    TASK = "Pick up each coloured jack and place it in the tray of the same colour."
    COLOURS = ("red", "green")
    ORACLE_GAIN = 0.7
    TRANSIT_GAIN = 1.0
    # Tray slots (centres, real metres) along the far side of the workspace; the episode draws which colour
    # goes where and jitters each by up to TRAY_JITTER_M.
    TRAY_SLOTS = np.array([[0.530, 0.030], [0.572, 0.030]])
    TRAY_JITTER_M = 0.003
    # Jacks lie on the near side, at least JACK_SPACING_M apart, turned at random about the vertical.
    JACK_REGION = np.array([[0.510, 0.590], [-0.040, -0.008]])
    JACK_SPACING_M = 0.022
    GRASP_ALONG_M = 0.6 * jacks.JACK_ARM_LENGTH   # grasp an upward arm this far out from the centre ...
    GRASP_DEPTH_M = 0.0015                         # ... with the tip this far below its axis (room for misjudged height)
    APPROACH_M = 0.004                             # pre-grasp height above the grasp point
    CLEARANCE_M = 0.003                            # carried jack's lowest point above the tray walls
    RELEASE_HEIGHT_M = 0.004                       # lowest point above the tray floor when the jaw opens
    IN_TRAY_HEIGHT_M = 0.003                       # success: at most this far above the resting height
    WELD_LIFT_M = 0.0025                           # the weld forms once the squeezed jack is lifted this much

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        n = len(self.COLOURS)
        box = lambda k: spaces.Box(-np.inf, np.inf, shape=(k,), dtype=np.float32)  # noqa: E731
        self.observation_space["observation"] = box(19 + 3 * n)
        self.observation_space["achieved_goal"] = box(3 * n)
        self.observation_space["desired_goal"] = box(3 * n)
        self.goal = np.zeros(3 * n)

    # ------------------------------------------------------------------ scene
    def build_scene(self) -> None:
        objects.make_rim(self.client, tip_clip_box()[:2], visual=self.visual)
        self.trays = [jacks.make_colour_tray(self.client, slot, jacks.COLOURS[c], visual=self.visual)
                      for slot, c in zip(self.TRAY_SLOTS, self.COLOURS)]
        self._jack_specs = [jacks.jack_spec(self.client, jacks.COLOURS[c], visual=self.visual) for c in self.COLOURS]
        self.jacks: list[int] = []
        self.respawn_objects()

    def respawn_objects(self) -> None:
        for body in self.jacks:
            self.client.removeBody(body)
        self.jacks = [jacks.spawn_jack(self.client, spec) for spec in self._jack_specs]
        self.object_id = self.jacks[0]

    def dynamic_bodies(self) -> list[int]:
        return list(self.jacks)

    def reset_task(self, rng):
        slots = self.TRAY_SLOTS[rng.permutation(len(self.COLOURS))]
        self.tray_centres = slots + rng.uniform(-self.TRAY_JITTER_M, self.TRAY_JITTER_M, size=slots.shape)
        for body, centre in zip(self.trays, self.tray_centres):
            jacks.move_tray(self.client, body, centre)
        placed: list[np.ndarray] = []
        while len(placed) < len(self.jacks):
            xy = rng.uniform(self.JACK_REGION[:, 0], self.JACK_REGION[:, 1])
            if all(np.linalg.norm(xy - p) >= self.JACK_SPACING_M for p in placed):
                placed.append(xy)
        for body, xy in zip(self.jacks, placed):
            jacks.place_jack(self.client, body, xy, jacks.objects.TABLE_TOP_Z, float(rng.uniform(0.0, 2 * np.pi)))
        start = np.array([WORKSPACE[0, 0], WORKSPACE[1, 1], WORKSPACE[2, 1]])
        return start, 0.0, physics.JAW_OPEN_RAD

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        obs, info = super().reset(seed=seed, options=options)
        for body in self.jacks:   # resting jacks sleep until something touches them
            self.client.changeDynamics(body, -1, activationState=physics.pb.ACTIVATION_STATE_SLEEP)
        self._start_z = {body: float(jacks.jack_pose(self.client, body)[0][2]) for body in self.jacks}
        return obs, info

    def sample_goal(self, rng):
        rest = jacks.tray_floor_z() + jacks.JACK_REST_HEIGHT
        return np.concatenate([[x, y, rest] for x, y in self.tray_centres])

    def goal_marker_position(self) -> np.ndarray:
        return np.array([0.55, 0.0, 0.0])   # under the table: the trays' colours show the goals

    # ------------------------------------------------------------------ grasping any jack
    def step(self, action):
        if not self.grasp.attached:
            # The jaws grasp whichever jack they are at: the one nearest the tip.
            tip = self.tip_pose()[:3, 3]
            self.grasp.object_id = min(self.jacks, key=lambda b: np.linalg.norm(jacks.jack_pose(self.client, b)[0] - tip))
        return super().step(action)

    def grasp_lift_condition(self) -> bool:
        body = self.grasp.object_id
        return jacks.jack_pose(self.client, body)[0][2] > self._start_z[body] + self.WELD_LIFT_M

    # ------------------------------------------------------------------ observation and success
    def jack_centres(self) -> np.ndarray:
        return np.array([jacks.jack_pose(self.client, b)[0] for b in self.jacks])

    def achieved_goal(self) -> np.ndarray:
        return self.jack_centres().reshape(-1)

    def in_tray(self, achieved_goal, desired_goal) -> np.ndarray:
        """Per jack (..., n): centre within the tray's walls and resting (not held above the floor)."""
        n = len(self.COLOURS)
        a = np.asarray(achieved_goal, dtype=np.float64).reshape(*np.shape(achieved_goal)[:-1], n, 3)
        d = np.asarray(desired_goal, dtype=np.float64).reshape(*np.shape(desired_goal)[:-1], n, 3)
        e = a - d
        return all_last(np.abs(e[..., :2]) < jacks.TRAY_INNER_HALF) & (np.abs(e[..., 2]) < self.IN_TRAY_HEIGHT_M)

    def is_success(self, achieved_goal, desired_goal) -> np.ndarray:
        return all_last(self.in_tray(achieved_goal, desired_goal))

    def _active_jack(self) -> int:
        placed = self.in_tray(self.achieved_goal(), self.goal)
        left = np.flatnonzero(~placed)
        return int(left[0]) if len(left) else len(self.jacks) - 1

    def object_state(self):
        pos, rot = jacks.jack_pose(self.client, self.jacks[self._active_jack()])
        return pos, pos, kin.euler_xyz(rot)

    def observation_vector(self) -> np.ndarray:
        return np.concatenate([super().observation_vector(), self.achieved_goal()])

    def _info(self, obs: dict) -> dict:
        info = super()._info(obs)
        info["jacks_in_trays"] = int(np.sum(self.in_tray(obs["achieved_goal"], obs["desired_goal"])))
        return info

    # ------------------------------------------------------------------ oracle
    def plan_oracle(self):
        plan = []
        yaw = float(self.robot_state()[5])
        for i, body in enumerate(self.jacks):
            plan += self._jack_plan(i, body, yaw)
            yaw = plan[-1]["yaw"]
        return plan

    def _jack_plan(self, i: int, body: int, current_yaw: float) -> list[dict]:
        """Waypoints that carry jack ``i`` into its tray, starting from a tool yaw of ``current_yaw``."""
        centre = jacks.jack_pose(self.client, body)[0]
        tips, yaws = jacks.arm_grasps(self.client, body, self.GRASP_ALONG_M, self.GRASP_DEPTH_M)
        # The jaw is symmetric: each arm can be grasped at its yaw or that plus π; take the least turn.
        yaws = np.array([y if abs(wrap_angle(y - current_yaw)) <= np.pi / 2 else wrap_angle(y + np.pi) for y in yaws])
        k = int(np.argmin(np.abs(wrap_angle(yaws - current_yaw))))
        offset, yaw = tips[k] - centre, float(yaws[k])
        hang = jacks.lowest_point_below(self.client, body, tips[k])   # lowest point of the jack below the tip
        carry_z = jacks.tray_wall_top_z() + self.CLEARANCE_M + hang
        release_lift = self.RELEASE_HEIGHT_M
        s = slice(3 * i, 3 * i + 3)

        def jack(obs):
            return np.asarray(obs["achieved_goal"][s], np.float64)

        def tip(obs):
            return np.asarray(obs["observation"][:3], np.float64)

        def above(obs):
            g = jack(obs) + offset
            return np.array([g[0], g[1], carry_z])

        def over_tray(obs):
            err = np.asarray(obs["desired_goal"][s], np.float64) - jack(obs)
            t = tip(obs)
            return np.array([t[0] + err[0], t[1] + err[1], carry_z])

        def lower(obs):
            err = np.asarray(obs["desired_goal"][s], np.float64) + [0.0, 0.0, release_lift] - jack(obs)
            return tip(obs) + err

        def retreat(obs):
            t = tip(obs)
            return np.array([t[0], t[1], carry_z])

        return [
            {"target": above, "yaw": yaw, "jaw": OPEN, "tol": 1.5e-3, "gain": self.TRANSIT_GAIN},
            {"target": lambda obs: jack(obs) + offset + [0.0, 0.0, self.APPROACH_M], "yaw": yaw, "jaw": OPEN,
             "tol": 1e-3},
            {"target": lambda obs: jack(obs) + offset, "yaw": yaw, "jaw": OPEN, "tol": 3e-4},
            {"target": lambda obs: jack(obs) + offset, "yaw": yaw, "jaw": CLOSE, "tol": 2e-3, "hold": 2},
            {"target": retreat, "yaw": yaw, "jaw": CLOSE, "tol": 2e-3, "gain": self.TRANSIT_GAIN},
            {"target": over_tray, "yaw": yaw, "jaw": CLOSE, "tol": 1e-3, "gain": self.TRANSIT_GAIN},
            {"target": lower, "yaw": yaw, "jaw": CLOSE, "tol": 1e-3},
            {"target": tip, "yaw": yaw, "jaw": OPEN, "tol": 1.0, "yaw_tol": 10.0, "hold": 1},
            {"target": retreat, "yaw": yaw, "jaw": OPEN, "tol": 2e-3, "gain": self.TRANSIT_GAIN},
        ]
