"""Physical realism of the PSM tasks under rough input: overlaps, tunnelling, grasps, slip, drops, tracking.

Usage: ``uv run python benchmarks/physics_realism.py [--episodes 30] [--tasks NeedlePick ...] [--workers 2]``

For every PSM task it runs ``episodes`` seeded episodes each of random actions (uniform in the unit box),
bang-bang actions (±1 on every axis, signs redrawn every 1–4 steps) and the task's oracle; then
scenario runs: a closed jaw poked down onto the object from 1 cm above and swiped sideways into it from
6 mm beside (neither may grasp), drop tests of the task's object from 0–60 mm onto its support, and a
free-space tracking test of every action direction of the unit box (26 bang-bang corners and faces, plus
random actions). A probe installed as the env's ``substep_hook`` measures after *every physics substep*:

* overlap (mm, real units) = the deepest penetration (negative ``getClosestPoints`` distance) per pair class:
  tool↔static (table, tray, board), tool↔object, object↔static, object↔object;
* held-object slip (mm): how far a held object has moved from where it sat in the hand when grasped;
* held-object overlap (mm): a held object's deepest overlap with the blades holding it and with static bodies
  (press-through).

The probe reads state without changing it: no forward-kinematics pass (the wrist's frame comes from the joint
positions), so an episode is bit-identical with and without it (tests/test_held_objects.py).

Held runs (``held-bang-bang``, ``held-spin``, ``held-press``) take the oracle until a hand has welded its object,
then give rough input with that hand's jaw kept closed; ``chatter`` closes and lifts a jaw just above a jack and
counts tip-pinch lifts.

Per episode it also counts objects that end below their support (centre of mass under the floor they rest on)
or out of the workspace (off the table), objects never held that end outside every tool tip's clip box ("pushed
out", out of reach; with how far beyond, mm), objects left inside a static body (> 1 mm at the end), drops (a grasp
lost while the jaw was still commanded closed), and grasps made when the object was not between the blades. Steps/s exclude
the probe's own time. Everything prints as one table.
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import time
from dataclasses import dataclass, field

import gymnasium as gym
import numpy as np
from rich.console import Console
from rich.progress import Progress
from rich.table import Table

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.envs import drawer, env_id, jacks, match_board, objects, peg_board, ring_board
from surrol_data.envs.psm import JAW_JOINTS
from surrol_data.envs import kinematics as kin
from surrol_data.envs.psm_env import WORKSPACE, tip_clip_box
from surrol_data.envs.tasks.match_board import MatchBoard
from surrol_data.envs.tasks.match_board_panel import MatchBoardPanel
from surrol_data.envs.tasks.pick_and_place import PickAndPlace
from surrol_data.envs.units import ACTION_POSITION_M, SCALING

TASKS = ["NeedleReach", "GauzeRetrieve", "NeedlePick", "PegTransfer", "NeedleRegrasp", "BiPegTransfer",
         "PickAndPlace", "MatchBoard", "MatchBoardPanel", "PegBoard", "NeedleRings"]
POLICIES = ["random", "bang-bang", "oracle"]
SCENARIOS = ["poke", "swipe", "drop", "tracking"]
# Rough input while holding: the oracle until a hand has welded its object, then HELD_STEPS steps of bang-bang
# actions, of the wrist spun back and forth at full speed, or of the tool pushed straight down, that hand's jaw
# kept closed; and a jaw chattering just above a jack (a tip-pinch must not lift it).
HELD_RUNS = ["held-bang-bang", "held-spin", "held-press"]
HELD_STEPS = 40
HELD_TASKS = [t for t in ["NeedleReach", "GauzeRetrieve", "NeedlePick", "PegTransfer", "NeedleRegrasp",
                          "BiPegTransfer", "PickAndPlace", "MatchBoard", "MatchBoardPanel", "PegBoard", "NeedleRings"]
              if t != "NeedleReach"]   # (NeedleReach's jaw is blocked closed)
CHATTER_TASKS = ["PickAndPlace"]
CHATTER_HEIGHT_M = 0.003   # above the oracle's grasp point on a jack's upward arm: the blade ends reach its sides
CHATTER_CLOSURES = 8       # per episode
TIP_PINCH_MAX_DEG = 135.0  # blade contact normals less than this apart: a tip-pinch, not the object across the gap
GRASPING_TASKS = ["GauzeRetrieve", "NeedlePick", "PegTransfer"]      # poke/swipe targets (single arm, jaw free)
DROP_TASKS = ["GauzeRetrieve", "NeedlePick", "PegTransfer"]          # gauze→tray floor, needle→pad, block→board
INSIDE_TOLERANCE_M = 0.001
_PLACE_ABOVE_M = 0.1   # drop tests: where an object is first put to measure how far its lowest point hangs down
OVERLAP_CLASSES = ("tool-static", "tool-object", "object-static", "object-object")
# Blade geometry (jaw link frame, metres) for the independent between-the-blades check: each blade's inner face
# is its link's x = 0 plane; the blade runs 10.2 mm along +y.
_BLADE_LENGTH_M, _FACE_TOL_M = 0.0102, 0.0003
_MIN_OPENING_RAD = np.deg2rad(2.0)   # blade 7 minus blade 6 (the jaw angle); a closed jaw reads 0 ± 1°


@dataclass
class Result:
    task: str
    run: str
    episodes: int = 0
    steps: int = 0
    step_time: float = 0.0
    overlap: dict = field(default_factory=lambda: {k: 0.0 for k in OVERLAP_CLASSES})
    below_support: int = 0
    out_of_workspace: int = 0
    pushed_out: int = 0             # objects never held that ended outside every tool tip's clip box (out of reach)
    pushed_out_by: float = 0.0      # ... the farthest of them beyond it (real metres)
    left_inside: int = 0
    grasps: int = 0
    grasps_not_between: int = 0
    drops: int = 0
    max_slip: float = 0.0
    tracking_error: float | None = None
    tracked_moves: int = 0          # free-space moves the tracking error is the worst of
    successes: int = 0

    held_blade: float = 0.0         # a held object's deepest overlap with a blade of the hand holding it
    held_static: float = 0.0        # ... and with a static body (press-through)
    tip_pinch_lifts: int = 0        # objects lifted by a grasp whose blades did not have it between their faces
    pinches: int = 0                # chatter closures that ended in a tip-pinch (blade_pair_angle < TIP_PINCH_MAX_DEG)

    def merge_overlaps(self, probe: "Probe") -> None:
        for k, v in probe.overlap.items():
            self.overlap[k] = max(self.overlap[k], v)
        self.held_blade = max(self.held_blade, probe.held["blade"])
        self.held_static = max(self.held_static, probe.held["static"])


# ---------------------------------------------------------------------- probe
def grasps_of(env) -> tuple:
    return tuple(env.grasps) if hasattr(env, "grasps") else (env.grasp,)


class Probe:
    """The substep hook: classifies the scene's bodies once per episode, then records the deepest overlaps."""

    def __init__(self):
        self.overlap = {k: 0.0 for k in OVERLAP_CLASSES}
        self.step_slip: dict[int, float] = {}   # per arm, the largest slip of its held object during this step
        self.step_touch: set[int] = set()       # tools that touched anything during this step
        self.held = {"blade": 0.0, "static": 0.0}   # a held object's deepest overlap with its hand's blades / statics
        self.held_ever: set[int] = set()        # objects a hand has held this episode (timed_step notes them)
        self.time = 0.0

    def attach(self, env) -> None:
        c = env.client
        self.env = env
        self.tools = [g.psm.body for g in grasps_of(env)]
        self.static, self.objects = [], []
        for i in range(c.getNumBodies()):
            b = c.getBodyUniqueId(i)
            if b in self.tools or b == env.goal_marker or not has_collision_shape(c, b):
                continue
            (self.static if c.getDynamicsInfo(b, -1)[0] == 0.0 else self.objects).append(b)
        self.pairs = ([("tool-static", a, b) for a in self.tools for b in self.static]
                      + [("tool-object", a, b) for a in self.tools for b in self.objects]
                      + [("object-static", a, b) for a in self.objects for b in self.static]
                      + [("object-object", a, b) for i, a in enumerate(self.objects) for b in self.objects[i + 1:]])
        env.substep_hook = self

    def detach(self, env) -> None:
        env.substep_hook = None

    def __call__(self, env) -> None:
        t = time.perf_counter()
        c = env.client
        for cls, a, b in self.pairs:
            pts = c.getClosestPoints(a, b, 0.0)
            if pts:
                depth = -min(p[8] for p in pts) / SCALING
                if depth > self.overlap[cls]:
                    self.overlap[cls] = depth
        for tool in self.tools:
            if tool not in self.step_touch and c.getContactPoints(bodyA=tool):
                self.step_touch.add(tool)
        for k, g in enumerate(grasps_of(env)):
            if not g.attached:
                continue
            for j in JAW_JOINTS:
                for p in c.getClosestPoints(g.psm.body, g.object_id, 0.0, linkIndexA=j):
                    self.held["blade"] = max(self.held["blade"], -p[8] / SCALING)
            for s in self.static:
                for p in c.getClosestPoints(g.object_id, s, 0.0):
                    self.held["static"] = max(self.held["static"], -p[8] / SCALING)
            rel = relative_pose(c, g.psm, g.object_id, getattr(g, "object_link", -1))
            # From where the hold began (the grasp's own reference: a hold made at reset, as NeedleRegrasp's, began
            # before the probe looked); a carried object's weld restored is the same hold (grasp.py, 6. Carry).
            slip = float(np.linalg.norm(rel - g.held_at)) / SCALING
            self.step_slip[k] = max(self.step_slip.get(k, 0.0), slip)
        self.time += time.perf_counter() - t

    def deepest(self, a: int, b: int) -> float:
        pts = self.env.client.getClosestPoints(a, b, 0.0)
        return -min((p[8] for p in pts), default=0.0) / SCALING


def has_collision_shape(c, body: int) -> bool:
    """A body without a collision shape (goal marker, endoscope) has a bounding box of zero size; a multibody may
    keep its shapes on its links only (the panel's drawer: a shapeless base at the cabinet).
    (``getCollisionShapeData`` cannot tell: it fails on maximal-coordinate bodies such as the needle.)"""
    for link in range(-1, c.getNumJoints(body)):
        lo, hi = c.getAABB(body, link)
        if any(h > l for l, h in zip(lo, hi)):
            return True
    return False


def relative_pose(c, psm, obj: int, link: int = -1) -> np.ndarray:
    """The held object's (its base's, or its ``link``'s) position in the wrist (EEF) frame, scaled units, read without
    a forward-kinematics pass (which would move the solver's next result, see Probe). After a physics step the joints,
    the colliders and a body's base are where the step left them, but PyBullet's stored link frames are still those
    the step began with: a base is read against the wrist's frame computed from the joint positions (Psm.wrist_frame;
    read against a blade's stored frame, a held object seemed a step's motion off its grip), a link (a drawer's
    handle) against the wrist's stored frame (a blade's, turned back by its joint), both from the step's start."""
    if link < 0:
        eef = psm.wrist_frame()
        pos, quat = c.getBasePositionAndOrientation(obj)
    else:
        blade = c.getLinkState(psm.body, JAW_JOINTS[0])
        half = 0.5 * c.getJointState(psm.body, JAW_JOINTS[0])[0]
        eef = c.multiplyTransforms(blade[4], blade[5], [0, 0, 0], [0, 0, -np.sin(half), np.cos(half)])
        pos, quat = c.getLinkState(obj, link)[:2]
    inv_p, inv_q = c.invertTransform(eef[0], eef[1])
    return np.asarray(c.multiplyTransforms(inv_p, inv_q, pos, quat)[0])


def blade_pair_angle(c, body: int, obj: int) -> float | None:
    """The widest angle (degrees) between a contact normal of one blade's inner-face touches of the object and one of
    the other's (as in ``between_blades``); None unless both blades touch it so. ~180°: the object lies across the gap
    between the faces; ~90°: a tip-pinch, the blade ends on two sides of it."""
    normals = [inner_face_touches(c, body, obj, j, towards_other) for j, towards_other in zip(JAW_JOINTS, (-1.0, 1.0))]
    if not all(normals):
        return None
    return max(float(np.degrees(np.arccos(np.clip(np.dot(a, b), -1.0, 1.0)))) for a in normals[0] for b in normals[1])


def inner_face_touches(c, body: int, obj: int, blade: int, towards_other: float) -> list:
    """The contact normals (world, object → blade) of the blade's touches of the object on its inner face: normal
    within 45° of the face's, at a point along the blade's length (not beyond its end)."""
    link = c.getLinkState(body, blade)   # (a blade has a collision shape: its stored frame is the step's)
    inv_p, inv_q = c.invertTransform(link[4], link[5])
    touches = []
    for p in c.getClosestPoints(body, obj, 0.0005 * SCALING, linkIndexA=blade):
        local = np.asarray(c.multiplyTransforms(inv_p, inv_q, p[6], [0, 0, 0, 1])[0]) / SCALING
        normal = np.asarray(c.multiplyTransforms([0, 0, 0], inv_q, p[7], [0, 0, 0, 1])[0])
        if -towards_other * normal[0] > np.cos(np.pi / 4) and -_FACE_TOL_M <= local[1] <= _BLADE_LENGTH_M:
            touches.append(np.asarray(p[7]))
    return touches


def between_blades(c, body: int, obj: int) -> bool:
    """Independent geometric check: does the object touch both blades on their inner faces, within the blades?

    A touch counts when the contact normal (object → blade) points across the closing gap, within 45° of the
    blade's inner-face normal, at a point along the blade's length (not beyond its end); and the blades must be
    apart (a closed jaw has nothing between them)."""
    q = [s[0] for s in c.getJointStates(body, JAW_JOINTS)]
    if q[1] - q[0] < _MIN_OPENING_RAD:
        return False
    return all(inner_face_touches(c, body, obj, j, towards_other) for j, towards_other in zip(JAW_JOINTS, (-1.0, 1.0)))


# ---------------------------------------------------------------------- scene facts
def support_z(task: str, xy: np.ndarray) -> float:
    """Height (real metres) of the surface an object at ``xy`` rests on."""
    if task in ("NeedleReach", "NeedlePick"):
        if abs(xy[0] - objects.TRAY_ORIGIN[0]) < 0.0505 and abs(xy[1]) < 0.085:
            return objects.PAD_TOP_Z
        inside = abs(xy[0] - objects.TRAY_ORIGIN[0]) < 0.0565 and abs(xy[1]) < 0.0935
        return objects.TRAY_ORIGIN[2] + 0.000181 if inside else objects.TABLE_TOP_Z
    if task == "GauzeRetrieve":
        inside = abs(xy[0] - objects.BARE_TRAY_ORIGIN[0]) < 0.0565 and abs(xy[1]) < 0.0935
        return objects.BARE_TRAY_FLOOR_Z if inside else objects.TABLE_TOP_Z
    if task in ("PegTransfer", "BiPegTransfer"):
        on_board = np.all(np.abs(xy - peg_board.BOARD_ORIGIN[:2]) < peg_board.BOARD_HALF_EXTENTS[:2])
        return peg_board.BOARD_ORIGIN[2] + peg_board.BOARD_HALF_EXTENTS[2] if on_board else objects.TABLE_TOP_Z
    if task == "PickAndPlace":   # a tray's floor (wherever the episode put the tray), or the table
        reach = jacks.TRAY_INNER_HALF + jacks.TRAY_WALL + PickAndPlace.TRAY_JITTER_M
        in_tray = np.any(np.all(np.abs(xy - PickAndPlace.TRAY_SLOTS) < reach, axis=1))
        return jacks.tray_floor_z() if in_tray else objects.TABLE_TOP_Z
    if task == "MatchBoard":     # a groove's floor over the board (the lowest a block rests there), or the table
        half = np.array([len(MatchBoard.GLYPHS) * match_board.CELL_PIXELS[0], match_board.CELL_PIXELS[1]]) \
            * match_board.PIXEL / 2
        on_board = np.all(np.abs(xy - MatchBoard.BOARD_ORIGIN[:2]) < half)
        return (objects.TABLE_TOP_Z + match_board.BOARD_THICKNESS - match_board.GROOVE_DEPTH if on_board
                else objects.TABLE_TOP_Z)
    if task == "MatchBoardPanel":   # the drawer's floor over the cabinet and the drawer's path, or the table
        d = xy - MatchBoardPanel.CABINET_CENTRE[:2]
        over = abs(d[0]) < 0.036 and -0.02 - drawer.TRAVEL < d[1] < 0.021
        return objects.TABLE_TOP_Z + drawer.FLOOR_TOP if over else objects.TABLE_TOP_Z
    if task == "PegBoard":
        on_board = np.all(np.abs(xy - ring_board.BOARD_CENTRE_XY) < ring_board.BOARD_HALF_EXTENTS[:2])
        return ring_board.BOARD_TOP_Z if on_board else objects.TABLE_TOP_Z
    return objects.TABLE_TOP_Z   # NeedleRegrasp, NeedleRings: the needle is held in the air; the table is what it falls to


def check_end(task: str, probe: Probe, res: Result) -> None:
    c = probe.env.client
    for obj in probe.objects:
        pos = np.asarray(c.getBasePositionAndOrientation(obj)[0]) / SCALING
        if pos[2] < support_z(task, pos[:2]):
            res.below_support += 1
        if pos[2] < objects.TABLE_TOP_Z - 0.01 or np.any(np.abs(pos[:2] - objects.TABLE_CENTRE[:2])
                                                          > objects.TABLE_HALF_EXTENTS[:2]):
            res.out_of_workspace += 1
        if any(probe.deepest(obj, s) > INSIDE_TOLERANCE_M for s in probe.static):
            res.left_inside += 1
        if obj not in probe.held_ever:
            # Pushed, never held: it must stay where a tool tip can still go (a held object reaches past the tip it
            # hangs from, and a dropped one lands where it falls; drops are counted).
            beyond = min(max(float(np.max(lo - pos[:2])), float(np.max(pos[:2] - hi)), 0.0)
                         for lo, hi in tip_boxes(probe.env))
            if beyond > 0.0:
                res.pushed_out += 1
                res.pushed_out_by = max(res.pushed_out_by, beyond)


def tip_boxes(env) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each arm's tip clip box in xy (low, high corners; real metres): its workspace and the target margin."""
    return [(box[:2, 0], box[:2, 1]) for box in map(tip_clip_box, getattr(env, "WORKSPACES", (WORKSPACE,)))]


# ---------------------------------------------------------------------- runs
def timed_step(env, action, res: Result, probe: Probe, jaw_closing: list[bool]):
    before = [g.attached for g in grasps_of(env.unwrapped)]
    probe.step_slip = {}
    probe.step_touch = set()
    t0, p0 = time.perf_counter(), probe.time
    obs, _, terminated, truncated, info = env.step(action)
    res.step_time += (time.perf_counter() - t0) - (probe.time - p0)
    res.steps += 1
    u = env.unwrapped
    probe.held_ever.update(g.object_id for g, was in zip(grasps_of(u), before) if was or g.attached)
    for k, (g, was, closing) in enumerate(zip(grasps_of(u), before, jaw_closing)):
        if g.attached and not was:
            res.grasps += 1
            if not between_blades(u.client, g.psm.body, g.object_id):
                res.grasps_not_between += 1
        if was and not g.attached and closing:
            res.drops += 1
        elif g.attached:   # slip of objects still held; a dropped object's last slip is what dropped it
            res.max_slip = max(res.max_slip, probe.step_slip.get(k, 0.0))
    return obs, info, terminated or truncated


def probed_episodes(env, task: str, res: Result, seeds, check: bool = True):
    """For each seed: reset, attach a fresh probe, yield ``(seed, obs, probe)`` for the caller to act; afterwards
    (``check``) count what the episode left below, outside or inside, and keep its deepest overlaps."""
    u = env.unwrapped
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        probe = Probe()
        probe.attach(u)
        yield seed, obs, probe
        if check:
            check_end(task, probe, res)
        res.merge_overlaps(probe)
        probe.detach(u)
        res.episodes += 1
    env.close()


def run_policy(task: str, policy: str, episodes: int, seeds=None) -> Result:
    """``episodes`` seeded episodes (seeds 0, 1, …; or the given ``seeds``) of the policy, probed."""
    env = gym.make(env_id(task))
    u = env.unwrapped
    res = Result(task, policy)
    dim = env.action_space.shape[0]
    for seed, obs, probe in probed_episodes(env, task, res, range(episodes) if seeds is None else seeds):
        rng = np.random.default_rng(1000 + seed)
        done, hold, action = False, 0, np.zeros(dim)
        info = {}
        while not done:
            if policy == "oracle":
                action = u.oracle_action(obs)
            elif policy == "random":
                action = rng.uniform(-1.0, 1.0, dim)
            elif hold == 0:
                action, hold = rng.choice([-1.0, 1.0], dim), int(rng.integers(1, 5))
            hold = max(hold - 1, 0)
            closing = [a < 0 for a in np.asarray(action).reshape(-1, 5)[:, 4]]
            obs, info, done = timed_step(env, action, res, probe, closing)
        res.successes += int(info.get("is_success", 0.0) > 0)
    return res


def move_tip(env, target: np.ndarray, jaw: float, res: Result, probe: Probe, steps: int = 30, gain=1.0):
    """Drive the single arm's tip to ``target`` with proportional actions (each axis at most ``gain``)."""
    u = env.unwrapped
    for _ in range(steps):
        err = (target - u.tip_pose()[:3, 3]) / ACTION_POSITION_M
        if np.linalg.norm(err) < 0.03:
            return
        a = np.clip(err, -gain, gain)
        timed_step(env, np.array([*a, 0.0, jaw]), res, probe, [jaw < 0])


def object_point(u, task: str) -> tuple[np.ndarray, np.ndarray]:
    """A point on the task object's top the jaws would close on, and the jaw-opening direction there."""
    if task == "NeedlePick":
        wp = u.needle_waypoint(1)
        _, rot = objects.needle_pose(u.client, u.object_id)
        return wp, rot[:, 0]
    if task == "GauzeRetrieve":
        return u.gauze_pose()[0] + np.array([0.0, 0.0, objects.GAUZE_HALF_EXTENTS[2]]), np.array([1.0, 0, 0])
    tips, yaws = peg_board.wall_grasps(u.client, u.object_id, 0.0)
    normal = np.array([np.cos(yaws[0]), np.sin(yaws[0]), 0.0])
    return tips[0] - normal * (peg_board.GRASP_RADIUS - 0.5 * (peg_board.BLOCK_OUTER_INRADIUS
                                                              + peg_board.BLOCK_HOLE_INRADIUS)), normal


def run_poke_swipe(task: str, kind: str, episodes: int) -> Result:
    """A closed jaw pushed onto the object from 1 cm above (poke), or swept into it from 6 mm beside (swipe)."""
    env = gym.make(env_id(task))
    u = env.unwrapped
    res = Result(task, kind)
    for seed, _, probe in probed_episodes(env, task, res, range(episodes)):
        point, opening = object_point(u, task)
        yaw = float(np.arctan2(opening[1], opening[0]))
        side = np.array([-np.sin(yaw), np.cos(yaw), 0.0])     # along the blades' width: no blade faces the object
        if kind == "poke":
            move_tip(env, point + [0, 0, 0.01], -1.0, res, probe, gain=0.6)
            for _ in range(4):
                timed_step(env, np.array([0, 0, -1.0, 0, -1.0]), res, probe, [True])
            for _ in range(3):
                timed_step(env, np.array([0, 0, 1.0, 0, -1.0]), res, probe, [True])
        else:
            direction = opening if seed % 2 else side
            start = point + 0.006 * direction
            move_tip(env, start + [0, 0, 0.012], -1.0, res, probe, gain=0.6)
            move_tip(env, start - [0, 0, 0.001], -1.0, res, probe, gain=0.3)
            for _ in range(3):
                timed_step(env, np.array([*(-direction[:2]), 0.0, 0, -1.0]), res, probe, [True])
            for _ in range(3):
                timed_step(env, np.array([0, 0, 1.0, 0, -1.0]), res, probe, [True])
    return res


def gap_to_surface(c, obj: int, statics: list[int], surface: float) -> float:
    """Height (real metres) of ``obj``'s lowest point above the horizontal support surface at ``surface``."""
    gaps = [p[8] / SCALING for s in statics for p in c.getClosestPoints(obj, s, 2 * _PLACE_ABOVE_M * SCALING)
            if abs(p[6][2] / SCALING - surface) < 1e-4]
    if not gaps:
        raise RuntimeError("drop test: no support surface found below the object")
    return min(gaps)


def run_drops(task: str, episodes: int) -> Result:
    """The task object released at rest, 0–60 mm above its support, in random orientations, and left to settle."""
    env = gym.make(env_id(task))
    u = env.unwrapped
    res = Result(task, "drop")
    heights = np.linspace(0.0, 0.06, 7)
    c = u.client
    for seed, _, probe in probed_episodes(env, task, res, range(episodes)):
        rng = np.random.default_rng(seed)
        pos = np.asarray(c.getBasePositionAndOrientation(u.object_id)[0]) / SCALING
        h = heights[seed % len(heights)]
        if task == "PegTransfer":   # between the pegs of the two clusters, well clear of every peg
            pos = peg_board.BOARD_ORIGIN + np.array([0.035, rng.uniform(-0.01, 0.01), 0.0])
        surface = support_z(task, pos[:2])
        quat = c.getQuaternionFromEuler(rng.uniform(-np.pi, np.pi, 3) if seed % 2 else [0, 0, rng.uniform(-3, 3)])
        # The drop height is that of the object's lowest point: place it well above, measure the gap, lower it.
        pos[2] = surface + _PLACE_ABOVE_M
        c.resetBasePositionAndOrientation(u.object_id, (pos * SCALING).tolist(), quat)
        pos[2] += h - gap_to_surface(c, u.object_id, probe.static, surface)
        c.resetBasePositionAndOrientation(u.object_id, (pos * SCALING).tolist(), quat)
        c.resetBaseVelocity(u.object_id, [0, 0, 0], [0, 0, 0])
        c.changeDynamics(u.object_id, -1, activationState=c.ACTIVATION_STATE_WAKE_UP)
        probe.held_ever.add(u.object_id)   # placed where it falls (PegTransfer's: beyond the tip's box), not pushed
        for _ in range(12):
            timed_step(env, np.array([0, 0, 0, 0, 1.0]), res, probe, [False])
    return res


def run_tracking(task: str, episodes: int) -> Result:
    """Free-space tracking: from a point clear of everything, each action held 2 steps; the error is relative
    to the commanded 1 cm per unit. Steps whose target is outside the clip box or the arm's reach, or during
    which the tool touched anything (at any physics step: the force-limited tool stalls on a peg top it meets),
    are not free-space moves and are skipped."""
    env = gym.make(env_id(task))
    u = env.unwrapped
    res = Result(task, "tracking")
    corners = [np.array(v, float) - 1.0 for v in np.ndindex(3, 3, 3) if v != (1, 1, 1)]
    rng = np.random.default_rng(0)
    actions = corners + [rng.uniform(-1, 1, 3) for _ in range(max(episodes - len(corners), 4))]
    bimanual = hasattr(u, "psms")
    worst = 0.0
    for i, _, probe in probed_episodes(env, task, res, range(len(actions)), check=False):
        a = actions[i]
        arm = i % 2 if bimanual else 0
        psm = u.psms[arm] if bimanual else u.psm
        ws = u.WORKSPACES[arm] if bimanual else WORKSPACE
        start = np.array([ws[0].mean(), ws[1].mean(), ws[2, 1] - 0.015])
        held = bimanual and u.HELD_AT_START == arm

        def act(delta):
            full = np.zeros(10 if bimanual else 5)
            full[5 * arm: 5 * arm + 3] = delta
            full[5 * arm + 4] = -1.0 if held else 1.0
            if bimanual:
                full[5 * (1 - arm) + 4] = -1.0 if u.HELD_AT_START == 1 - arm else 1.0
            return full

        def tip():
            return (u.tip_pose(arm) if bimanual else u.tip_pose())[:3, 3].copy()

        for _ in range(30):
            err = (start - tip()) / ACTION_POSITION_M
            if np.linalg.norm(err) < 0.03:
                break
            timed_step(env, act(np.clip(err, -1, 1)), res, probe, [held, False])
        for _ in range(2):
            tip0 = tip()
            want = a * ACTION_POSITION_M
            target = tip0 + want
            box = tip_clip_box(ws)
            clipped = np.any(target < box[:, 0]) or np.any(target > box[:, 1])
            reachable = psm.ik(kin.pose_from(target, (u.tip_pose(arm) if bimanual else u.tip_pose())[:3, :3]))
            timed_step(env, act(a), res, probe, [held, False])
            touched = psm.body in probe.step_touch
            if clipped or not reachable.within_limits or touched:
                continue
            res.tracked_moves += 1
            worst = max(worst, float(np.linalg.norm(tip() - tip0 - want) / np.linalg.norm(want)))
    res.tracking_error = worst
    return res


def hold_then(env, task: str, res: Result, probe: Probe, obs, steps: int = 150):
    """The oracle until some hand has welded its object; returns (the observation, that arm) or None."""
    u = env.unwrapped
    for _ in range(steps):
        held = [g.welded for g in grasps_of(u)]
        if any(held):
            return obs, held.index(True)
        action = u.oracle_action(obs)
        obs, _, _ = timed_step(env, action, res, probe, [a < 0 for a in np.asarray(action).reshape(-1, 5)[:, 4]])
    return None


def run_held(task: str, kind: str, episodes: int, seeds=None) -> Result:
    """Rough input while holding (HELD_RUNS): the oracle until a hand has welded its object, then HELD_STEPS steps
    of bang-bang actions, of the wrist spun back and forth at full speed (the other axes still), or of the tool
    pushed straight down, that hand's jaw commanded closed throughout."""
    env = gym.make(env_id(task))
    u = env.unwrapped
    res = Result(task, kind)
    dim = env.action_space.shape[0]
    for seed, obs, probe in probed_episodes(env, task, res, range(episodes) if seeds is None else seeds):
        held = hold_then(env, task, res, probe, obs)
        if held is None:
            continue
        obs, arm = held
        rng = np.random.default_rng(1000 + seed)
        hold, action = 0, np.zeros(dim)
        for i in range(HELD_STEPS):
            if kind == "held-bang-bang":
                if hold == 0:
                    action, hold = rng.choice([-1.0, 1.0], dim), int(rng.integers(1, 5))
                hold = max(hold - 1, 0)
            else:
                action = np.zeros(dim)
                if kind == "held-spin":
                    action[5 * arm + 3] = 1.0 if (i // 4) % 2 == 0 else -1.0
                else:
                    action[5 * arm + 2] = -1.0
            a = np.array(action, dtype=float)
            a[5 * arm + 4] = -1.0
            timed_step(env, a, res, probe, [x < 0 for x in a.reshape(-1, 5)[:, 4]])
    return res


def run_chatter(task: str, episodes: int, seeds=None) -> Result:
    """A jaw chattering CHATTER_HEIGHT_M above the oracle's grasp point on a jack's upward arm: closed for 2 steps,
    lifted 9 mm closed, opened and lowered back, 8 times per episode. Each closure is aimed afresh at the jack where
    it now lies (the closures before nudge it: at a fixed point, PickAndPlace seed 4's jack came to lie with its arm
    across the blades' ends, 135–163° normals, and was rightly gripped). There the blade ends reach the arm's sides
    from above: a tip-pinch (both inner faces touching, contact normals less than 135° apart: ``pinches``), which
    must not grasp; counted as a tip-pinch lift when a jack rose more than 5 mm with the jaw holding it."""
    env = gym.make(env_id(task))
    u = env.unwrapped
    res = Result(task, "chatter")
    c = u.client
    g = u.grasp
    rule, seen = g.between_blades, []

    def watched() -> bool:   # the grasp rule, asked at every physics step of a closure: the blades' normals then
        angles = [a for a in (blade_pair_angle(c, u.psm.body, j) for j in u.jacks) if a is not None]
        seen.extend(angles)
        return rule()

    g.between_blades = watched
    for seed, obs, probe in probed_episodes(env, task, res, range(episodes) if seeds is None else seeds):
        while u._wp_index < 2:   # the oracle's approach over its first jack, jaw open
            obs, _, _ = timed_step(env, u.oracle_action(obs), res, probe, [False])
        wp = u.oracle_waypoints[2]
        for _ in range(CHATTER_CLOSURES):
            seen.clear()
            target = (wp["target"](obs) if callable(wp["target"]) else wp["target"]) + [0.0, 0.0, CHATTER_HEIGHT_M]
            move_tip(env, target, 0.5, res, probe, steps=20, gain=0.5)
            before = np.array([c.getBasePositionAndOrientation(j)[0][2] for j in u.jacks])
            for _ in range(2):
                obs, info, _ = timed_step(env, np.array([0, 0, 0, 0, -1.0]), res, probe, [True])
            res.pinches += bool(seen) and max(seen) < TIP_PINCH_MAX_DEG
            for _ in range(3):
                obs, info, _ = timed_step(env, np.array([0, 0, 0.6, 0, -1.0]), res, probe, [True])
            after = np.array([c.getBasePositionAndOrientation(j)[0][2] for j in u.jacks])
            if info["grasped"] and np.max(after - before) / SCALING > 0.005:
                res.tip_pinch_lifts += 1
            obs, _, _ = timed_step(env, np.array([0, 0, 0, 0, 1.0]), res, probe, [False])
            for _ in range(3):
                obs, _, _ = timed_step(env, np.array([0, 0, -0.6, 0, 1.0]), res, probe, [False])
    return res


def run_job(job: tuple) -> Result:
    task, run, episodes = job
    if run in POLICIES:
        return run_policy(task, run, episodes)
    if run in HELD_RUNS:
        return run_held(task, run, episodes)
    if run == "chatter":
        return run_chatter(task, episodes)
    if run in ("poke", "swipe"):
        return run_poke_swipe(task, run, episodes)
    if run == "drop":
        return run_drops(task, episodes)
    return run_tracking(task, episodes)


def jobs_for(tasks: list[str], runs: list[str], episodes: int) -> list[tuple]:
    jobs = []
    for task in tasks:
        for run in runs:
            if run in ("poke", "swipe") and task not in GRASPING_TASKS:
                continue
            if run == "drop" and task not in DROP_TASKS:
                continue
            if (run in HELD_RUNS and task not in HELD_TASKS) or (run == "chatter" and task not in CHATTER_TASKS):
                continue
            jobs.append((task, run, episodes))
    # Longest first, so the two workers finish together.
    weight = {"BiPegTransfer": 4, "PegTransfer": 3, "NeedleRegrasp": 2}
    return sorted(jobs, key=lambda j: -weight.get(j[0], 1) * (3 if j[1] in POLICIES else 1))


def print_table(results: list[Result], episodes: int) -> None:
    table = Table(title=f"physics realism ({episodes} episodes per row; overlaps and slip in mm, real units, "
                        "max over every physics substep; targets: overlap ≤ 1.0, slip ≤ 2 or a counted drop, "
                        "0 tunnelled / inside / not-between grasps, tracking ≤ 10 %)")
    cols = ["task", "run", "tool↔static", "tool↔object", "object↔static", "object↔object", "below support",
            "out of ws", "pushed out", "left inside", "grasps", "not between", "drops", "max slip", "held↔blade",
            "held↔static", "tip-pinches", "tip-pinch lifts", "tracking err",
            "success", "steps/s"]
    for col in cols:
        table.add_column(col, justify="left" if col in ("task", "run") else "right")
    order = {r: i for i, r in enumerate(POLICIES + SCENARIOS + HELD_RUNS + ["chatter"])}
    for r in sorted(results, key=lambda r: (TASKS.index(r.task), order[r.run])):
        def mm(v, limit=1.0):
            s = f"{1000 * v:.2f}"
            return f"[red]{s}[/red]" if 1000 * v > limit else s

        def count(n):
            return f"[red]{n}[/red]" if n else "0"

        table.add_row(r.task, r.run, *(mm(r.overlap[k]) for k in OVERLAP_CLASSES),
                      count(r.below_support), count(r.out_of_workspace),
                      f"[red]{r.pushed_out} ({1000 * r.pushed_out_by:.1f})[/red]" if r.pushed_out else "0",
                      count(r.left_inside), str(r.grasps),
                      count(r.grasps_not_between), str(r.drops), mm(r.max_slip, 2.0), mm(r.held_blade),
                      mm(r.held_static), f"{r.pinches}/{CHATTER_CLOSURES * r.episodes}" if r.run == "chatter" else "—",
                      count(r.tip_pinch_lifts),
                      "—" if r.tracking_error is None else
                      (f"{100 * r.tracking_error:.1f} % of {r.tracked_moves}" if r.tracking_error <= 0.1
                       else f"[red]{100 * r.tracking_error:.1f} % of {r.tracked_moves}[/red]"),
                      f"{r.successes}/{r.episodes}" if r.run == "oracle" else "—",
                      f"{r.steps / r.step_time:.0f}" if r.step_time else "—")
    Console(width=260).print(table)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tasks", nargs="+", default=TASKS, choices=TASKS)
    runs = POLICIES + SCENARIOS + HELD_RUNS + ["chatter"]
    parser.add_argument("--runs", nargs="+", default=runs, choices=runs)
    parser.add_argument("--episodes", type=int, default=30, help="episodes per task and run (≥ 30 for the study)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    jobs = jobs_for(args.tasks, args.runs, args.episodes)
    results = []
    with Progress(transient=True) as progress:
        bar = progress.add_task("task × run", total=len(jobs))
        with mp.get_context("spawn").Pool(args.workers) as pool:
            for r in pool.imap_unordered(run_job, jobs):
                results.append(r)
                progress.advance(bar)
    print_table(results, args.episodes)


if __name__ == "__main__":
    main()
