"""Physics constants (the one place for them) and the PyBullet client every scene is built in.

The original SurRoL integrates one 0.2 s control period with 48 sub-steps of 1/240 s and 50 solver
iterations. Our scene uses primitive collision shapes (boxes, capsules) instead of VHACD meshes and a
coarser integration (``SUBSTEPS`` per control period), which keeps contacts stable at this scale
(the PSM scene is 5× real size) while making a step ~20× cheaper. Where the coarse step is not enough —
something fast about to hit something — it is refined locally (adaptive_steps.py) instead of everywhere.
Every value below says which measurement chose it; ``benchmarks/physics_realism.py`` (overlaps, tunnelling,
grasps, slip, tracking, measured at every physics step) and ``benchmarks/env_throughput.py`` (speed) watch
both sides of the trade, and tests/test_physics_realism.py keeps them true.

Measured and rejected (benchmarks/physics_realism.py, 3–5-episode probes): a closed jaw sank 1.2–1.8 mm into
the pad because Bullet's box-box test reports no contact before boxes overlap (fixed by hull blades, see
shapes.py), not because of the step. Against a tool pressing an object into a static body (pokes, swipes;
the object sank 1.5–9 mm, with the heavy arm of the time), none of these helped enough to keep: 24 or 48
sub-steps, 60 or 200 solver iterations alone (200 halved it at 4× the cost), contact stiffness on the objects or the statics,
the MLCP solvers, and the gauze as a rigid body (maximal coordinates). A block pushed down by an external force
alone (no tool) does not sink even at 60 N: the press-in came from the arm, whose position motors pushed with
up to 60 N·m (and, under the adaptive sub-steps, up to 8× more: see psm_env._set_time_step) through heavy links.

What removed most of it is the dVRK's own arrangement: a light, gravity-compensated arm whose joint motors are
force limited, so a tool stalls against a rigid obstacle instead of driving through it (benchmarks/
physics_realism.py, 10 episodes: PegTransfer pokes 8.6 → 1.6 mm, none left inside instead of 21 of 30;
bang-bang PegTransfer 0.2 mm), while unit-box actions are still tracked within 2.7 % in free space. The limits
that would keep every poke under 1 mm leave BiPegTransfer's oracle at 91 % (see PSM_MAX_FORCE). What took the
rest (1.3–2.3 mm left) is the contact solver on that arm (SOLVER_ITERATIONS, CONTACT_ERP below), and counting a
tumbling object's spin in the adaptive sub-steps (a needle flicked by a poke landed 1.9–2.2 mm deep).
"""

from __future__ import annotations

import atexit
import contextlib
import ctypes
import functools
import os
import sys
import weakref

import numpy as np

from surrol_data.envs.units import CONTROL_PERIOD_S, SCALING

GRAVITY = (0.0, 0.0, -9.81)
SUBSTEPS = 12                     # physics steps per control period
TIME_STEP = CONTROL_PERIOD_S / SUBSTEPS
# Contact solver. A tool pressing an object onto a static body is a chain of constraints (the force-limited motor,
# tool↔object, object↔static) that Gauss-Seidel resolves only over many iterations, and whatever it leaves unresolved
# the contact ERP corrects by that fraction per step. Deepest object↔static overlap (mm) in benchmarks/
# physics_realism.py rows, with the spin-aware sub-steps: 20 iterations and ERP 0.2 (PyBullet's defaults) 1.09 /
# 1.52 / 1.28 / 1.35 for needle poke / needle swipe / block poke / block swipe (4 episodes each) and 3.22 under
# random BiPegTransfer actions (a block wedged on a peg, creeping in with no tool touching it); 50 iterations alone
# ≤ 0.98 on pokes and swipes but 3.04 under PegTransfer bang-bang; ERP 0.8 alone 2.09 (needle swipe) and 4.71
# (block swipe); 30 iterations and ERP 0.8 1.56 (block swipe) and 5.25 under BiPegTransfer bang-bang (blocks jammed
# against pegs and each other); 50 iterations and ERP 0.8 ≤ 0.87 in every row of the full benchmark (10 episodes:
# every PSM task under random, bang-bang and oracle actions, pokes, swipes, drops), nothing left inside. ERP 0.8
# also lets a resting object sit on its support (a needle on the pad rested 0.36 mm deep at ERP 0.2, 0.03 mm at
# 0.8); at ERP 1.0 (100 iterations) a poked needle was flung off the pad spinning at 18 rad/s.
# Cost, oracle episodes of the same run (5 × 3, medians): NeedlePick −3 %, PegTransfer −2 %, GauzeRetrieve −12 %,
# BiPegTransfer −10 % of the steps/s at (20, 0.2); ERP alone costs nothing measurable. Left at (50, 0.8), 30
# episodes: under bang-bang input a block jammed on a peg sank 2–3 mm into it and was flung off the board (PegTransfer
# seeds 2 and 19, 1 of 30 BiPegTransfer episodes); 100 iterations kept those two seeds clean but jammed another
# (PegTransfer bang-bang, 30 episodes: 3.18 mm, one block flung off). That was friction, not the iterations: see
# PEG_BOARD_FRICTION.
SOLVER_ITERATIONS = 50
CONTACT_ERP = 0.8
# The error reduction of the non-contact constraints while a grasp's weld (a JOINT_FIXED constraint between the wrist
# link and the object) holds something; PyBullet's default otherwise. At the default (0.2) the weld corrected a fifth of
# its error per physics step and the held object crept in the hand under a force of ~2 N, a tenth of the weld's limit:
# a block held down on MatchBoard's board slipped 2.4 mm within 2 steps and a blade stood 1.35 mm inside it (seed 2;
# the blades held by their stops, see Psm.hold_blades), a jack pushed down on PickAndPlace 1.54 mm inside a blade (seed
# 2). At 0.8 0.64 and 0.28 mm, at 1.0 0.29 and 0.21 mm (held-object runs of benchmarks/physics_realism.py). A
# constraint's own ``erp`` (changeConstraint) changes nothing for a multibody's fixed constraint: only the global value
# reaches it. Not everywhere: at 0.8 or 1.0 throughout, GauzeRetrieve's gauze, let go 16 mm over the tray, landed
# turned on its edge (tests/test_kinematic_carry.py), as it does not at the default.
CONSTRAINT_ERP = 1.0
DEFAULT_CONSTRAINT_ERP = 0.2
SETTLE_STEPS = 4                  # physics steps after a reset before the first observation

# Joint PD control (PyBullet's position+velocity motor): gains, and limits on motor force and velocity.
# Velocity limits are real units (rad/s; m/s for insertion), converted to the scaled scene where needed.
PSM_POSITION_GAIN = 0.4
PSM_VELOCITY_GAIN = 1.0
# Force limits (N·m / N, scaled scene), as the dVRK's current limits: the most a tool pushes with, so it stalls on
# a rigid obstacle. Measured on PegTransfer pokes (a closed jaw driven down onto a block wall, 5 episodes),
# free-space tracking of the unit box, and the oracles: at (60, 60, 60, 10, 10, 10) the block sank 7.7 mm into the
# board; at (0.5, 0.5, 0.5) 0.3 mm, but the tool could not drag the MatchBoardPanel drawer (0 of 3); at (1, 1, 0.5)
# 0.6 mm, but BiPegTransfer's oracle, carrying the block 3 mm over the peg tops, caught it on a peg in 9 of 100
# episodes (91 %; at (1.5, 1.5, 0.75) it still failed 3). At (2, 2, 1) BiPegTransfer's oracle is back to
# 99 of 100 and a poked or swiped block sinks 1.6–2.3 mm (a needle 1.3–1.5 mm), tracking 2.7 %. The
# wrist's 0.1 pushes ~2 N at the blade ends, ~70× a blade's weight; the jaws squeeze with JAW_MAX_FORCE. These
# limits only work with light, gravity-compensated links (below): at 3× the link mass below, forces (1, 1, 1)
# tracked a unit action with 19 % error.
PSM_MAX_FORCE = (2.0, 2.0, 1.0, 0.1, 0.1, 0.1)
# Joint speed limits. A full diagonal action (1, ±1, ±1) asks for 17.3 mm of tip motion per 0.2 s step; with
# the tip ~0.14 m below the RCM that needs ~0.6 rad/s of outer yaw/pitch and ~0.09 m/s of insertion, and the PD
# must get there within the step. At (0.35, 0.35, 0.07) a (1, −1, 1) action moved 10–14 mm (41 % tracking
# error, benchmarks/physics_realism.py "tracking"); at (1.0, 1.0, 0.2) every unit-box action is tracked within
# ~1 %. Faster moves into contact are what the adaptive sub-steps below are for.
PSM_MAX_VELOCITY = (1.0, 1.0, 0.2, 3.0, 3.0, 3.0)            # rad/s, m/s (real)
# Jaw squeeze. The blades stop on the object at first touch (the grasp grips at that physics step and holds each
# blade there), so the squeeze force only matters while closing. With the heavy arm (links 0.1), 0.01–0.1 let a
# block wall pry a closed jaw open and 4 pried a blade 1 mm into a needle; with the light arm below, 0.1 keeps
# pokes and swipes grasp-free and the blades within 0.5 mm of what they touch (with 0.3 on the jaws and the
# wrist, a poked block sank 1.1 mm).
JAW_MAX_FORCE = 0.1
# Link inertia (scaled scene). The arm is light, as the motors' force limits require (inertia is what they must
# accelerate: 1 cm in 0.2 s from rest): mass 0.01 / inertia 1e-3 tracked a unit action with 19 % error at forces
# (1, 1, 1), 0.003 / 3e-4 within 2.7 %. Its weight is compensated (Psm.compensate_gravity, every physics
# step), as on the dVRK, so that the force limits are not spent holding the arm up (without it, 60× lower motor
# forces than the old ones let the old arm sag > 100 % off its targets). Links whose inertia about their joint is
# near zero make the articulated solver ill-conditioned (contacts then swing the jaws and wrist far from their
# targets), so the diagonal stays 0.1 × the mass (in scaled m²), the ratio the old values had.
PSM_LINK_MASS = 0.003
PSM_LINK_INERTIA = 3e-4
JAW_MASS = 0.003
JAW_INERTIA = 3e-5
JAW_MAX_VELOCITY = 4.0            # rad/s
JAW_OPEN_RAD = np.deg2rad(40.0)   # the env's "open" jaw command
JAW_CLOSED_RAD = 0.0

# ECM (endoscope) joint control. The reference runs its ECM tasks at a 0.1 s control period of 24 × 1/240 s
# steps of PyBullet's position motor with its default gains (Kp 0.1, Kd 1: each step closes 10 % of the error,
# at most max-velocity × dt). The ECM touches nothing, so ecm.py integrates exactly that recurrence in closed
# form instead of simulating it step by step; the velocity limits bound large commands (real units).
ECM_CONTROL_PERIOD_S = 0.1
ECM_SUBSTEPS = 24
ECM_POSITION_GAIN = 0.1
ECM_MAX_VELOCITY = (1.0, 1.0, 0.2, 2.0)   # yaw, pitch (rad/s), insertion (m/s), roll (rad/s)

# A commanded tip move ramps the joint targets over this many of the control period's physics steps (then
# holds): the PD then moves the tool at a steady speed instead of covering most of the move in its first two
# physics steps at the joints' speed limits (peak tip speed ~3× lower for the same move, so impacts sink in
# ~3× less), and the remaining steps let it settle, so a step still tracks its action within ~1 %.
RAMP_STEPS = 8

# Adaptive sub-stepping (adaptive_steps.py): a coarse step is split so that no fast body near another travels
# more than this per physics step; contacts then catch it before it sinks deeper than about that much.
MAX_TRAVEL_PER_STEP_M = 0.001            # tools: under bang-bang input, ~1 mm of travel sank ~0.7 mm at most
MAX_OBJECT_TRAVEL_PER_STEP_M = 0.0005    # falling objects: 1 mm per step let a needle dropped 60 mm sink 1.01 mm
# MatchBoard's glyph blocks: a flat block of 7–11 pixel boxes lands on its groove's floor with all its boxes at once
# (~40 contact points), and the solver's uneven share among them tips it: released ~4 mm over the floor, the oracle's
# block bounced, turned 2.4° within one physics step and sank an edge in (benchmarks/physics_realism.py, MatchBoard
# oracle, 30 episodes: 0.77–1.03 mm, the 5 deepest ≥ 0.86). At 0.25 mm per step the same 5 seeds read 0.41–0.58 mm.
# Everywhere (every object's limit) it cost PegTransfer 12 % and PickAndPlace 9 % of their steps/s (one process,
# alternating, 4 × 5 oracle episodes) where their objects land within the limit at 0.5 mm, so it is MatchBoard's.
FLAT_BLOCK_TRAVEL_PER_STEP_M = 0.00025
# Needles: a needle dropped from the air lands on its arc and rocks there; at the coarse step a rocking needle that had
# come almost to rest (its far end moving ~0.3 mm a step) was kicked by its own contacts 1.05 mm into the table
# (NeedleRegrasp, random actions, seed 1; refined, 0.02 mm). At 0.25 mm per step the same 10 seeds read ≤ 0.74 mm.
# The hand-over scenes' (NeedleRegrasp, NeedleRings): NeedlePick's oracle, at this limit, failed 5 of 5 seeds (its
# reset left the needle 1.1 mm above its rest; not investigated), so NeedlePick keeps the objects' limit.
NEEDLE_TRAVEL_PER_STEP_M = 0.00025
MAX_REFINEMENT = 8
# A tool's period is refined only for a body it moves towards fast enough to close the gap within the period
# (tool_sweep.py: a bound on its links' motion along the gap's normal, from the joints' ranges of motion). The
# distance alone (any body within the period's reach, whichever way the tool moved) refined GauzeRetrieve's oracle
# at 1.40 physics steps per coarse step, 1.03 with the direction (5 episodes); over 6 episodes each of oracle,
# random and bang-bang actions on GauzeRetrieve and NeedlePick no tool came within 4.3 mm of anything in a period
# the direction left unrefined (tests/test_adaptive_steps.py keeps it so).

# Thin static floors (the tray's 0.36 mm base, its 5.2 mm pad) get collision boxes this deep below their top.
FLOOR_COLLISION_DEPTH_M = 0.01

# Contact and grasp.
JAW_FRICTION = 1.0
OBJECT_FRICTION = 1.0
# The peg board's: PyBullet's default, which the reference's board (no friction in its URDF) has, against the blocks'
# 1.0 (theirs sets it), i.e. μ = 0.5 between them (Bullet multiplies the two). At 1.0 on both, a block could jam on its
# peg: traced at every physics step (PegTransfer bang-bang, seed 2), a swipe turned a block 20° about its peg and the
# tool left it holding the peg in a corner of its hole; touching nothing but the board, its contacts with the peg and
# with the floor pushed each other in (normal forces 0.5 → 40 N on a 0.1 N block; μ = 1 locks a right-angled wedge:
# the friction of each contact stops the other's correction), sank in ~0.03 mm per physics step, and at 2.8 mm the
# correction flung the block off the board at 0.9 m/s, spinning at 50 rad/s. benchmarks/physics_realism.py, 30
# episodes, the failing ones at μ 1.0: PegTransfer bang-bang seeds 2 and 19 (block ↔ board 2.8, 2.9 mm, flung off) and
# 26 (the tool pressed 2.1 mm into a jammed block), BiPegTransfer bang-bang seed 24 (3.1 mm, flung off); at 0.5 each
# ≤ 0.79 mm (block ↔ board ≤ 0.21), nothing flung. Rejected: Bullet's pyramid friction instead of its cone (PyBullet's
# enableConeFriction=0, which bullet3 issue #1473 suggests for contacts that gain energy) mended those, but jammed
# PegTransfer random seed 29 and BiPegTransfer bang-bang seeds 2, 3, 5, 27 (2.7–5.0 mm; at board μ 0.5 with the cone
# they read ≤ 0.2 mm); friction ERP 0, split impulse and a zero restitution threshold changed nothing.
PEG_BOARD_FRICTION = 0.5
# A blade within this distance of the object touches it (real metres). 0.8 mm (the old value) clamped the
# jaw at 15° on a 1.24 mm needle wire (the blades had not reached it); 0.2 mm reads ~9° (the wire's width).
# A closing jaw near its object is also sub-stepped so that a blade comes no nearer than this per physics step
# (adaptive_steps.py): at the coarse step it covered ~1.1 mm per step and a block was gripped 0.45 mm inside a
# blade; refined, the grip finds both blades within 0.2 mm, outside the block (BiPegTransfer's oracle, seed 0).
GRASP_CONTACT_DISTANCE_M = 0.0002
BLADE_LENGTH_M = 0.0102             # jaw blade length (the reference's jaw collision box)
GRASP_MAX_FORCE = 20.0              # the weld's force limit (reference: maxForce 20)
# The grip before the task's lift condition holds stands in for the squeezing jaws' friction: 2.0 let the
# 50 g gauze slide 1.6 mm in the hand while the oracle lifted it; 5.0 (~10× its weight) holds it within 0.1 mm.
GRASP_FRICTION_FORCE = 5.0
# Nothing lies between the blades of a closed jaw. The thinnest thing held, the 1.24 mm needle wire, keeps the
# jaw at least 2·asin(0.62/10.2) ≈ 7° open; a closed jaw reads 0 ± 1°. Below this opening the blades' inner
# faces may both touch an object only from inside it (a closed jaw pushed 3 mm into a block wall "gripped" it).
GRASP_MIN_OPENING_RAD = float(np.deg2rad(3.0))
# A blade found inside the object deeper than this does not touch it from outside and grips nothing: the closing jaw
# is sub-stepped so that a blade comes at most GRASP_CONTACT_DISTANCE_M nearer per physics step, so a deeper blade
# closed through the object or was left in it by a drop (then the jaw, still commanded closed, re-gripped a MatchBoard
# block with a blade 1.95 mm inside it).
GRASP_MAX_BLADE_DEPTH_M = 0.0005
# A held object pressed into a static body deeper than this slips out of the hand (Grasp.gives): the weld would push it
# on through (a block 1.32 mm into MatchBoard's board). Contacts are those of the physics step's collision pass,
# which the step's own motion may deepen by a few tenths of a millimetre: hence 0.6, not the 1 mm limit.
GRASP_MAX_PRESS_M = 0.0006
GRASP_MAX_SLIP_M = 0.002            # a held object this far from where it was gripped is dropped (the 2 mm)


def scaled_velocity_limits() -> np.ndarray:
    v = np.array(PSM_MAX_VELOCITY, dtype=np.float64)
    v[2] *= SCALING
    return v


def _disconnect_at_exit(ref: weakref.ref) -> None:
    # BulletClient.__del__ of a client still alive at interpreter exit runs after os/pybullet are torn
    # down and raises TypeError; disconnecting it while the interpreter is whole makes __del__ a no-op.
    client = ref()
    if client is not None and getattr(client, "_client", -1) >= 0:
        with contextlib.suppress(Exception):
            client.disconnect()


class NoDisplayError(RuntimeError):
    """``render_mode="human"`` where no X display answers: PyBullet's window would end the whole process."""


def _x_display_problem() -> str | None:
    """Why PyBullet's window could not open here (Linux: an X display must answer), or None."""
    import socket

    if not sys.platform.startswith("linux"):
        return None
    name = os.environ.get("DISPLAY", "")
    if not name:
        return "DISPLAY is unset"
    host, _, rest = name.rpartition(":")
    number = rest.split(".")[0]
    if not number.isdigit():
        return f"DISPLAY={name!r} is not an X display name"
    if host in ("", "unix"):   # a local server: its socket (a file, or Linux's abstract namespace)
        addresses = [(socket.AF_UNIX, f"/tmp/.X11-unix/X{number}"), (socket.AF_UNIX, f"\0/tmp/.X11-unix/X{number}")]
    else:
        addresses = [(socket.AF_INET, (host, 6000 + int(number)))]
    for family, address in addresses:
        with socket.socket(family, socket.SOCK_STREAM) as s:
            s.settimeout(2.0)
            try:
                s.connect(address)
                return None
            except OSError:
                continue
    return f"no X server answers at DISPLAY={name!r}"


def make_client(gui: bool = False, renderer: bool = True) -> Client:
    """A fresh PyBullet world with this project's physics settings (no module-level client anywhere).

    ``renderer=False``, for a world that is never rendered (no camera, no render mode): PyBullet's built-in
    TinyRenderer is unloaded. Otherwise every body created builds render meshes (of its collision shapes when it
    has no visual ones), more than half the cost of an env's reset; the physics never reads them."""
    problem = _x_display_problem() if gui else None
    if problem:   # checked here: PyBullet itself would exit the process, not raise
        raise NoDisplayError(
            f"render_mode='human' opens a PyBullet window, which needs an X display, but {problem}. Run it on a "
            "desktop, or in a virtual display (`apt-get install xvfb`, then `xvfb-run -a python ...`); or use "
            "render_mode='rgb_array' (images, no window)")
    with _stdout_silenced(not gui):
        client = Client(connection_mode=pb.GUI if gui else pb.DIRECT)
    atexit.register(_disconnect_at_exit, weakref.ref(client))
    if not renderer and not gui:
        # Loading an already loaded plugin returns its id; unloaded, the server has no renderer to feed.
        plugin = client.loadPlugin("tinyRendererPlugin")
        if plugin >= 0:
            client.unloadPlugin(plugin)
    configure(client)
    if gui:
        client.configureDebugVisualizer(pb.COV_ENABLE_GUI, 0)
    return client


def configure(client: BulletClient) -> None:
    client.setGravity(*GRAVITY)
    client.setPhysicsEngineParameter(fixedTimeStep=TIME_STEP, numSolverIterations=SOLVER_ITERATIONS,
                                     contactERP=CONTACT_ERP, erp=DEFAULT_CONSTRAINT_ERP, numSubSteps=0,
                                     deterministicOverlappingPairs=1)


@contextlib.contextmanager
def _stdout_silenced(enabled: bool = True, fds: tuple[int, ...] = (1,)):
    """PyBullet's C code prints banners (build time on import, "argv[0]=" on connect); keep them out of
    progress output and logs by pointing the C-level file descriptors at /dev/null meanwhile."""
    if not enabled:
        yield
        return
    sys.stdout.flush()
    sys.stderr.flush()
    try:
        saved = {fd: os.dup(fd) for fd in fds}
    except OSError:  # no real file descriptors (some notebook kernels): nothing to silence
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        for fd in fds:
            os.dup2(devnull, fd)
        yield
    finally:
        with contextlib.suppress(Exception):
            ctypes.CDLL(None).fflush(None)  # C-level buffered prints go to /dev/null too
        for fd, copy in saved.items():
            os.dup2(copy, fd)
            os.close(copy)
        os.close(devnull)


with _stdout_silenced(fds=(1, 2)):
    import pybullet as pb
    from pybullet_utils.bullet_client import BulletClient


class Client(BulletClient):
    """PyBullet's client wrapper, with each function it binds to the client kept for the next call.

    BulletClient binds the client id afresh (an ``inspect`` test and a new partial, ~2 µs) on every attribute
    access, and an env step makes dozens of calls: binding once per name removes that cost, the calls are the
    same. Disconnecting forgets the bindings (PyBullet hands a disconnected client's id on to the next one)."""

    def __getattr__(self, name):
        attribute = super().__getattr__(name)
        if name == "disconnect":
            for key in [k for k, v in self.__dict__.items() if isinstance(v, functools.partial)]:
                del self.__dict__[key]
        elif isinstance(attribute, functools.partial):
            self.__dict__[name] = attribute
        return attribute
