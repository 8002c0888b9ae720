"""How far a tool can close the gap to a nearby body within one control period, along the gap's direction.

The adaptive sub-steps (adaptive_steps.py) refine a period when a fast tool could come near another body in it.
Distance alone says "near" whenever the tool passes over a tray wall or a floor, whichever way it moves (the
GauzeRetrieve oracle's tool, moving down and away from the wall it starts beside, was refined in 4 of 5 of its
first moves). Which way the tool moves is known: the motors head for the commanded joint targets. For convex
shapes, the gap ``d`` between a link and a body is a convex function of the link's displacement, so it cannot
fall below its tangent: after a displacement ``Δp`` of the closest point, ``d' ≥ d + Δp·n`` (``n`` the contact
normal, pointing from the body to the tool). The link cannot reach the body within the period if ``d`` exceeds

* the most the closest point can move against ``n``: joint by joint, ``Δp·n = Σ c_j Δq_j`` with ``c_j`` the
  point's Jacobian column along ``n``, maximised over each joint's range of motion in the period (between
  where it is, where its target is and where its current speed would carry it, widened by a slack);
* what rotation adds for the link's other points (the link turns by at most the sum of its revolute joints'
  moves, ``θ``; to first order a turn moves a point along the normal only by its offset across the normal,
  and no point of the link lies farther from the closest one than its bounding box allows);
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

# The joints (0–7) that move each colliding tool link, from the RCM out: wrist pitch link 4, jaws 6 and 7.
_CHAINS = {4: (0, 1, 2, 3, 4), 6: (0, 1, 2, 3, 4, 5, 6), 7: (0, 1, 2, 3, 4, 5, 7)}
_PRISMATIC = 2                      # the insertion; the others are revolute
_JOINTS = tuple(range(8))
# Slack on each joint's range of motion in a period: a fraction of the range plus a floor (rad; insertion in
# scaled metres). Measured out of contact over GauzeRetrieve/NeedlePick oracle episodes: the PD overshoots a
# ramped move by < 1 % (outer joints), the jaws by up to 16 % of their move.
_SLACK_FRACTION = 0.25
_SLACK_ABS = (0.002, 0.002, 0.002, 0.01, 0.02, 0.02, 0.02, 0.02)


class ToolSweep:
    """One tool's possible motion over the coming control period (built once per period)."""

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

    def may_close(self, link: int, point, normal, gap: float, aabb) -> bool:
        """Can ``link``'s closest point ``point`` (scaled world), ``gap`` away from a body along ``normal`` (from
        the body to the tool), close that gap within the period? ``aabb``: the link's bounding box."""
        if gap <= 0.0:
            return True
        px, py, pz = point
        nx, ny, nz = normal
        approach = 0.0     # the most the point may move against the normal
        turn = 0.0         # θ: the most the link may turn (sum of its revolute joints' moves)
        tilt = 0.0         # the same, weighted by how far each turn tilts the normal's plane: Σ move·|n × a|
        second = 0.0       # the Jacobian's change over the period, times the joints' moves
        columns = []       # (joint's move, |column|, θ of the joints before it; |column| < 0: the insertion)
        lo, hi, moves = self._lo, self._hi, self._moves
        for j in _CHAINS[link]:
            ax, ay, az = self._axes[j]
            move = moves[j]
            if j == _PRISMATIC:
                c = ax * nx + ay * ny + az * nz
                columns.append((move, -1.0, turn))
            else:
                ox, oy, oz = self._origins[j]
                rx, ry, rz = px - ox, py - oy, pz - oz
                # column = a × r (the point's velocity per unit joint speed); along the normal: (a × r)·n
                cx, cy, cz = ay * rz - az * ry, az * rx - ax * rz, ax * ry - ay * rx
                c = cx * nx + cy * ny + cz * nz
                columns.append((move, math.sqrt(cx * cx + cy * cy + cz * cz), turn))
                turn += move
                tx, ty, tz = ny * az - nz * ay, nz * ax - nx * az, nx * ay - ny * ax
                tilt += move * math.sqrt(tx * tx + ty * ty + tz * tz)
            approach += max(-c * lo[j], -c * hi[j])
        # The point's own move due to the joints from j outwards (D_j), for each j from the outermost in.
        outward = 0.0
        for move, size, before in reversed(columns):
            if size < 0.0:   # the insertion: its axis turns with the joints before it
                outward += move
                second += move * before
            else:            # |Δ column| ≤ θ_before·|column| (turned rigidly) + D_j (the point moved)
                outward += move * size
                second += move * (before * size + outward)
        # The link's other points, relative to the closest one: a turn by θ about an axis a moves a point at
        # offset r along the normal by θ·r·(n × a) to first order (only r's part across the normal counts),
        # and by at most θ²/2·|r| more. Offsets are bounded by the link's bounding box's corners.
        (x0, y0, z0), (x1, y1, z1) = aabb
        across = extent = 0.0
        for x in (x0 - px, x1 - px):
            for y in (y0 - py, y1 - py):
                for z in (z0 - pz, z1 - pz):
                    along = x * nx + y * ny + z * nz
                    r2 = x * x + y * y + z * z
                    across = max(across, r2 - along * along)
                    extent = max(extent, r2)
        others = tilt * math.sqrt(max(across, 0.0)) + 0.5 * turn * turn * math.sqrt(extent)
        return gap <= approach + others + second


def _z_axis(q):
    x, y, z, w = q
    return (2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y))
