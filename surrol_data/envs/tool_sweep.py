"""How far a tool can close the gap to a nearby body within one control period, along the gap's direction.

The adaptive sub-steps (adaptive_steps.py) refine a period when a fast tool could come near another body in it.
Distance alone says "near" whenever the tool passes over a tray wall or a floor, whichever way it moves (the
GauzeRetrieve oracle's tool, moving down and away from the wall it starts beside, was refined in 4 of 5 of its
first moves). Which way the tool moves is known: the motors head for the commanded joint targets.

For a convex link ``A`` and a convex body ``B`` a gap ``d`` apart, with closest points ``p`` on ``A`` and
``q = p − d·n`` on ``B`` (``n`` the contact normal, from the body to the tool), the plane through ``q`` normal
to ``n`` separates them: every point ``x`` of the link has ``(x − q)·n ≥ d``. The link cannot touch the body
within the period unless one of its points moves by at least ``d`` against ``n``. For a reference point ``c``
of the link (its bounding box's centre), a point ``x`` moves by ``Δc + (R − I)(x − c)``, so against ``n`` by
at most

* what ``c`` may move: joint by joint ``Δc·n = Σ J_j·n Δq_j`` (``J_j`` the Jacobian column of joint ``j`` at
  ``c``), maximised over each joint's range of motion in the period (between where it is, where its target is
  and where its current speed would carry it, widened by a slack);
* what the link's turn adds: the link turns by at most ``θ``, the sum of its revolute joints' moves; to first
  order a turn ``δ`` about an axis ``a`` moves ``x`` along ``n`` by ``δ (x − c)·(n × a)``, i.e. only by the
  offset's part across ``n``, and by at most ``1.5 θ² |x − c|`` more (the turn's second order, composing the
  joints' turns, their axes turning meanwhile); offsets are bounded by the box's corners;
* what the Jacobian's change over the period adds (its columns turn with the joints before them and change
  with the point's own move: second order in the joint moves).

These bounds hold as long as the joints stay within their ranges. Contact forces can push them out (a tool
pressed on the floor is deflected), but a tool in contact has a gap ≤ 0 and is refined anyway; the slack
(``_SLACK_FRACTION``, ``_SLACK_ABS``) covers the motors' overshoot out of contact, and
benchmarks/physics_realism.py (overlaps at every physics step) checks that nothing gets through.
"""

from __future__ import annotations

import math

from surrol_data.envs.physics import pb

# The joints (0–7) that move each colliding tool link, from the RCM out: wrist pitch link 4, jaws 6 and 7; and the
# wrist-yaw link 5, which carries nothing that collides but what a grasp holds (adaptive_steps: a carried object).
_CHAINS = {4: (0, 1, 2, 3, 4), 5: (0, 1, 2, 3, 4, 5), 6: (0, 1, 2, 3, 4, 5, 6), 7: (0, 1, 2, 3, 4, 5, 7)}
_PRISMATIC = 2                      # the insertion; the others are revolute
_JOINTS = tuple(range(8))
# Slack on each joint's range of motion in a period: a fraction of the range plus a floor (rad; insertion in
# scaled metres). Measured out of contact over GauzeRetrieve/NeedlePick oracle episodes: the PD overshoots a
# ramped move by < 1 % (outer joints), the jaws by up to 16 % of their move.
_SLACK_FRACTION = 0.25
_SLACK_ABS = (0.002, 0.002, 0.002, 0.01, 0.02, 0.02, 0.02, 0.02)


class ToolSweep:
    """One tool's possible motion over the coming control period (built once per period, when needed)."""

    def __init__(self, psm, states, period: float):
        """``states``: the tool's joint states (Psm.moving_joint_states) now; ``period``: seconds."""
        lo, hi = [], []
        for state, target, slack_abs in zip(states, psm.goal_targets, _SLACK_ABS):
            q, v = state[0], state[1]
            a = min(0.0, target - q, v * period)
            b = max(0.0, target - q, v * period)
            slack = _SLACK_FRACTION * (b - a) + slack_abs
            lo.append(a - slack)
            hi.append(b + slack)
        self._lo, self._hi = lo, hi
        self._moves = [max(-a, b) for a, b in zip(lo, hi)]   # the most each joint may move
        frames = pb.getLinkStates(psm.body, _JOINTS, 0, 1, physicsClientId=psm._cid)
        self._origins = [f[4] for f in frames]
        # A joint turns about (slides along) the z axis of its link's frame.
        self._axes = [_z_axis(f[5]) for f in frames]
        self._links: dict[int, tuple] = {}

    def _link(self, link: int, aabb) -> tuple:
        """What does not depend on the normal, for one link: its columns at the reference point with their
        joints' ranges, the revolute joints' axes with their moves, θ, the second-order term and the box's
        corners relative to the reference point."""
        (x0, y0, z0), (x1, y1, z1) = aabb
        px, py, pz = 0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.5 * (z0 + z1)
        lo, hi, moves = self._lo, self._hi, self._moves
        columns = []       # (J·n's x, y, z, joint's lower, upper move)
        turns = []         # (axis x, y, z, joint's move) of the revolute joints
        sizes = []         # (joint's move, |column| (< 0: the insertion), θ of the joints before it)
        turn = 0.0
        for j in _CHAINS[link]:
            ax, ay, az = self._axes[j]
            move = moves[j]
            if j == _PRISMATIC:
                columns.append((ax, ay, az, lo[j], hi[j]))
                sizes.append((move, -1.0, turn))
                continue
            ox, oy, oz = self._origins[j]
            rx, ry, rz = px - ox, py - oy, pz - oz
            cx, cy, cz = ay * rz - az * ry, az * rx - ax * rz, ax * ry - ay * rx    # a × r
            columns.append((cx, cy, cz, lo[j], hi[j]))
            turns.append((ax, ay, az, move))
            sizes.append((move, math.sqrt(cx * cx + cy * cy + cz * cz), turn))
            turn += move
        # Second order: |Δ column| ≤ θ_before·|column| (turned rigidly by the joints before it) + D_j (the point's
        # own move due to the joints from j outwards); the insertion's axis turns with the joints before it.
        second = outward = 0.0
        for move, size, before in reversed(sizes):
            if size < 0.0:
                outward += move
                second += move * before
            else:
                outward += move * size
                second += move * (before * size + outward)
        corners = [(x, y, z) for x in (x0 - px, x1 - px) for y in (y0 - py, y1 - py) for z in (z0 - pz, z1 - pz)]
        extent = math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2 + (z1 - z0) ** 2) / 2
        # The turn's second-order part: (1 − cos θ)·|x − c| ≤ θ²/2·|x − c|, as much again for composing the joints'
        # turns into one (and for their axes turning meanwhile).
        data = (columns, turns, second + 1.5 * turn * turn * extent, corners)
        self._links[link] = data
        return data

    def may_close(self, link: int, normal, gap: float, aabb) -> bool:
        """Can ``link`` (bounding box ``aabb``, scaled world) close a ``gap`` (scaled) to a body along ``normal``
        (from the body to the tool) within the period? ``aabb`` must be the same for every call on a link."""
        if gap <= 0.0:
            return True
        data = self._links.get(link)
        if data is None:
            data = self._link(link, aabb)
        columns, turns, fixed, corners = data
        nx, ny, nz = normal
        approach = 0.0     # the most the reference point may move against the normal
        for cx, cy, cz, lo, hi in columns:
            c = cx * nx + cy * ny + cz * nz
            approach -= c * lo if c > 0.0 else c * hi          # max(−c·lo, −c·hi), lo ≤ 0 ≤ hi
        if gap > approach + fixed and turns:
            tilt = 0.0     # Σ move·|n × a|
            for ax, ay, az, move in turns:
                tx, ty, tz = ny * az - nz * ay, nz * ax - nx * az, nx * ay - ny * ax
                tilt += move * math.sqrt(tx * tx + ty * ty + tz * tz)
            across = 0.0   # the largest offset across the normal, squared
            for x, y, z in corners:
                along = x * nx + y * ny + z * nz
                across = max(across, x * x + y * y + z * z - along * along)
            return gap <= approach + fixed + tilt * math.sqrt(across)
        return True

    def turn_reach(self, joints, aabb) -> float:
        """The most any point of a box (``aabb``, scaled world) fixed to the links past ``joints`` (revolute) may
        move relative to the link before them within the period: each joint's move times the box's farthest
        corner's distance from the joint's origin (an arc no longer than the angle times the radius)."""
        (x0, y0, z0), (x1, y1, z1) = aabb
        travel = 0.0
        for j in joints:
            ox, oy, oz = self._origins[j]
            radius = math.sqrt(max(abs(x0 - ox), abs(x1 - ox)) ** 2 + max(abs(y0 - oy), abs(y1 - oy)) ** 2
                               + max(abs(z0 - oz), abs(z1 - oz)) ** 2)
            travel += self._moves[j] * radius
        return travel


def _z_axis(q):
    x, y, z, w = q
    return (2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y))
