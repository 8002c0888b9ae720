"""The task's scene in Rerun as meshes that move: pad, tray, board, pegs, blocks, needle, gauze and the instruments.

A recorded episode stores actions and observations, not the pose of every body, so the scene is *replayed*:
the task's env is reset with the episode's seed (its provenance's ``env_id`` and ``seed``) and driven by the
recorded actions (the envs are deterministic: ``benchmarks/env_fingerprint.py``). After the reset and after each
action the world pose of every link that has a visual shape is read from PyBullet.

Logged under ``world/<L>/scene/body<b>/link<k>``: an ``rr.Mesh3D`` once (static: the link's visual shapes merged,
in the link's frame, real metres, with vertex colours), and an ``rr.Transform3D`` per step (one
``send_columns`` per link). The meshes are those the renderers draw (:mod:`surrol_data.render.body_shapes`, and
for the instruments and the needle :mod:`surrol_data.envs.instrument_geometry`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import rerun as rr

from surrol_data.envs import primitive_meshes
from surrol_data.render import body_shapes


@dataclass
class LinkMesh:
    body: int
    link: int
    positions: np.ndarray   # (N, 3) real metres, link frame
    normals: np.ndarray     # (N, 3)
    triangles: np.ndarray   # (M, 3)
    colours: np.ndarray     # (N, 4) uint8


@dataclass
class SceneReplay:
    meshes: list[LinkMesh]
    translations: np.ndarray   # (T+1, K, 3) real metres, one column per mesh
    quaternions: np.ndarray    # (T+1, K, 4) xyzw
    tip_drift_m: float = 0.0   # the largest distance between the replayed and the recorded tool tip
    notes: list[str] = field(default_factory=list)


def _rotation(q) -> np.ndarray:
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def link_meshes(client, scene_scale: float) -> tuple[list[LinkMesh], dict]:
    """Every link with visual shapes (primitives, OBJ meshes) as one mesh in its link frame (real metres), and per
    body the base's inertial-from-link transform that :func:`link_poses` needs."""
    meshes, inertial = [], {}
    for i in range(client.getNumBodies()):
        body = client.getBodyUniqueId(i)
        per_link: dict[int, list] = {}
        for shape in client.getVisualShapeData(body):
            link, kind, dims, local_pos, local_orn, rgba = shape[1], shape[2], shape[3], shape[5], shape[6], shape[7]
            mesh = body_shapes.visual_mesh(kind, dims, shape[4])
            if mesh is None:
                continue
            rot = _rotation(local_orn)
            placed = primitive_meshes.Mesh((mesh.positions @ rot.T + np.asarray(local_pos)) / scene_scale,
                                 mesh.normals @ rot.T, mesh.uvs, mesh.triangles)
            colour = np.round(np.clip(np.asarray(rgba, float), 0, 1) * 255).astype(np.uint8)
            per_link.setdefault(link, []).append((placed, np.repeat(colour[None], len(placed.positions), 0)))
        if not per_link:
            continue
        inertial[body] = client.invertTransform(*body_shapes.base_inertial_frame(client, body))
        for link, parts in sorted(per_link.items()):
            merged = primitive_meshes.merge(*[m for m, _ in parts])
            meshes.append(LinkMesh(body, link, merged.positions, merged.normals, merged.triangles,
                                   np.concatenate([c for _, c in parts])))
    return meshes, inertial


def link_poses(client, meshes: list[LinkMesh], inertial: dict, scene_scale: float) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) translations (real metres) and (K, 4) quaternions of the meshes' links now. A body that is gone
    (removed or respawned under another id) keeps NaN, which the caller replaces by its last pose."""
    present = {client.getBodyUniqueId(i) for i in range(client.getNumBodies())}
    by_body: dict[int, list[int]] = {}
    for m in meshes:
        by_body.setdefault(m.body, []).append(m.link)
    poses = {}
    for body, links in by_body.items():
        if body in present:
            for link, pose in body_shapes.link_world_poses(client, body, links, inertial[body]).items():
                poses[(body, link)] = pose
    t = np.full((len(meshes), 3), np.nan)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (len(meshes), 1))
    for k, m in enumerate(meshes):
        if (m.body, m.link) in poses:
            pos, orn = poses[(m.body, m.link)]
            t[k] = np.asarray(pos) / scene_scale
            q[k] = orn
    return t, q


def replay_scene(env_id: str, seed: int, actions: np.ndarray, tip_position: np.ndarray | None = None) -> SceneReplay:
    """Reset ``env_id`` with ``seed``, apply ``actions`` and read every link's pose after the reset and each
    action; ``tip_position`` (T+1, arms, 3), when given, is compared with the replay's (``tip_drift_m``)."""
    import gymnasium as gym

    import surrol_data.envs  # noqa: F401  (registers the ids)
    from surrol_data.render.env_view import EnvEndoscope

    env = gym.make(env_id, render_mode="rgb_array")
    try:
        _, info = env.reset(seed=int(seed))
        u = env.unwrapped
        client = u.client
        scale = EnvEndoscope(env).scene_scale   # how much larger than real the task builds its scene
        meshes, inertial = link_meshes(client, scale)
        translations, quaternions, tips = [], [], [info.get("tip_position")]
        t, q = link_poses(client, meshes, inertial, scale)
        translations.append(t)
        quaternions.append(q)
        for action in np.asarray(actions, np.float32):
            _, _, _, _, info = u.step(action)
            t, q = link_poses(client, meshes, inertial, scale)
            t = np.where(np.isnan(t), translations[-1], t)
            translations.append(t)
            quaternions.append(q)
            tips.append(info.get("tip_position"))
    finally:
        env.close()
    replay = SceneReplay(meshes, np.stack(translations), np.stack(quaternions))
    if tip_position is not None and all(tip is not None for tip in tips):
        replayed = np.asarray(tips, np.float64).reshape(len(tips), -1, 3)
        recorded = np.asarray(tip_position, np.float64).reshape(len(tips), -1, 3)
        replay.tip_drift_m = float(np.abs(replayed - recorded).max()) if replayed.shape == recorded.shape else np.inf
    if replay.tip_drift_m > 0.001:
        replay.notes.append(f"the replayed tool tip is up to {replay.tip_drift_m * 1000:.1f} mm from the recorded one "
                            "(the episode was recorded with another version of the env or other options)")
    return replay


def log_scene(rec: rr.RecordingStream, root: str, replay: SceneReplay, states: list) -> None:
    """Meshes once (static) and a transform per step (``states``: the T+1 steps' time columns)."""
    for k, m in enumerate(replay.meshes):
        entity = f"{root}/body{m.body}/link{m.link}"
        rec.log(entity, rr.Mesh3D(vertex_positions=m.positions, triangle_indices=m.triangles,
                                  vertex_normals=m.normals, vertex_colors=m.colours), static=True)
        rec.send_columns(entity, indexes=states,
                         columns=rr.Transform3D.columns(translation=replay.translations[:, k],
                                                        quaternion=replay.quaternions[:, k]))
