"""Log episodes to Rerun so demos of different sources can be compared side by side.

Entity layout, one subtree per episode label ``<L>`` (labels are made path-safe, see :func:`entity_label`)::

    world                          right-hand Z-up, metres (static view coordinates)
    world/<L>/arm<i>/path          full tool-tip path (static); in an intervention session each step's segment in
                                   the label colour where the policy drove, in OPERATOR_COLOUR where the operator did
    world/<L>/arm<i>/trail         tool-tip path up to the current step (grows over time)
    world/<L>/arm<i>/tip           current tool-tip point
    world/<L>/arm<i>/instrument    the PSM instrument as lines: shaft through the RCM, wrist, two jaw blades at the
                                   recorded opening (when the arms' RCM positions are given and no scene is)
    world/<L>/scene/body<b>/link<k>  with ``scene=True``: the task's bodies and instruments as meshes (logged
                                   once) moved by a transform per step, from a replay of the episode
                                   (:mod:`surrol_data.viz.scene_meshes`)
    world/<L>/object               object position (tasks with an object)
    world/<L>/goal                 goal marker(s)
    plots/<L>/action               action channels dx, dy, dz, dyaw, jaw (per arm)
    plots/<L>/jaw_angle            jaw angle per arm, rad
    plots/<L>/flags                device flags (clutch, jaw_button; intervention: the operator drove) as 0/1
    plots/<L>/policy_action        intervention sessions: the policy's proposed action beside the executed one
    plots/<L>/reward, plots/<L>/success
    camera/<L>/<camera>            camera images
    provenance/<L>                 markdown document: provenance and outcome

Recording properties: one property per label (the label itself as name) with the flattened provenance
and the outcome (``outcome.success``, ``outcome.steps_to_success``, ``outcome.path_length_cm``, ...).

Timelines: ``step`` (sequence) and ``time`` (duration, step × CONTROL_PERIOD_S seconds). States, tip
positions, jaw angles and images are indexed 0..T (the reset state is step 0). Action ``a_t`` and the
device flags that produced it are at step t (0..T-1); the reward and success that *result* from ``a_t``
describe state t+1 and are placed at step t+1, so success lights up on the frame where the tip is at the goal.

Everything is sent with ``send_columns`` (one call per entity and episode), which is orders of magnitude
faster than per-step ``log`` calls.
"""

from __future__ import annotations

import io
import re
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from surrol_data.datasets.trajectory import DEVICE_FLAGS, INTERVENTION, Trajectory
from surrol_data.envs.units import CONTROL_PERIOD_S
from surrol_data.datasets.metrics import trajectory_proficiency

APPLICATION_ID = "surrol_data"
# Object position columns of the PSM task observation (NeedlePick & co.): tip (3), yaw, jaw..., object (3).
PSM_OBJECT_POSITION = slice(7, 10)
ACTION_NAMES = ("dx", "dy", "dz", "dyaw", "jaw")

# Distinct colours per label (matplotlib's tab10 values), so sources are told apart in the shared 3-D view.
_PALETTE = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
            (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]

# The path where the operator drove, in an intervention session: a colour of no label (gold).
OPERATOR_COLOUR = (255, 200, 0)

Item = tuple[str, Trajectory, Mapping]


def entity_label(label: str) -> str:
    """Path-safe form of an episode label: anything but letters, digits, ``_ - .`` becomes ``_``.

    Done here rather than with Rerun's escaping so entity paths stay readable and predictable
    (``"BC policy"`` → ``world/BC_policy/...``).
    """
    if not label or not label.strip():
        raise ValueError("episode label must be a non-empty string")
    return re.sub(r"[^A-Za-z0-9_.\-]", "_", label.strip())


def log_trajectories(rec_or_path: rr.RecordingStream | str | Path, items: Sequence[Item], *,
                     object_position: slice | None = PSM_OBJECT_POSITION,
                     trail_length: int | None = None,
                     jpeg_quality: int | None = None,
                     send_blueprint: bool = True,
                     recording_name: str | None = None,
                     rcm_positions: Sequence[np.ndarray] | None = None,
                     scene: bool = False) -> rr.RecordingStream | Path:
    """Log episodes ``(label, trajectory, provenance)`` into one recording, one entity subtree per label.

    ``rec_or_path``: a :class:`rerun.RecordingStream` whose sinks the caller owns (returned as is), or
    a file path, in which case a headless ``.rrd`` is written and closed (see :func:`save_rrd`; the path
    is returned).
    ``object_position``: observation columns holding the object position; ``None`` for tasks without an
    object. Skipped when the observation is narrower than the slice.
    ``trail_length``: number of past tip positions in the growing trail; ``None`` keeps the whole history
    (cost grows as T², fine for episodes of a few hundred steps).
    ``jpeg_quality``: JPEG-compress camera frames (1..100) instead of logging raw RGB.
    ``rcm_positions``: the remote centre of motion of each PSM arm (world metres, see
    :func:`surrol_data.viz.instrument.psm_rcm_positions`); with them each arm's instrument is drawn.
    ``scene``: replay each episode in its env (provenance ``env_id`` and ``seed``) and log the scene's bodies and
    instruments as meshes with a transform per step (a few seconds per episode).
    """
    if isinstance(rec_or_path, (str, Path)):
        return save_rrd(rec_or_path, items, object_position=object_position, trail_length=trail_length,
                        jpeg_quality=jpeg_quality, send_blueprint=send_blueprint, recording_name=recording_name,
                        rcm_positions=rcm_positions, scene=scene)
    rec = rec_or_path
    names = _check_items(items, scene=scene)
    if recording_name:
        rec.send_recording_name(recording_name)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    for k, (name, (label, traj, provenance)) in enumerate(zip(names, items)):
        _log_episode(rec, name, label, traj, dict(provenance), _PALETTE[k % len(_PALETTE)],
                     object_position=object_position, trail_length=trail_length, jpeg_quality=jpeg_quality,
                     rcm_positions=rcm_positions, scene=scene)
    if send_blueprint:
        rec.send_blueprint(make_blueprint(items))
    return rec


def save_rrd(path: str | Path, items: Sequence[Item], *, recording_id: str | None = None, **kwargs) -> Path:
    """Write the episodes to a headless ``.rrd`` file (no viewer is spawned) and return its path.

    ``kwargs`` are those of :func:`log_trajectories`. ``recording_id`` defaults to the file stem so that
    re-writing the same file gives the same recording identity.
    """
    path = Path(path)
    if path.suffix != ".rrd":
        raise ValueError(f"save_rrd: {path} should end in .rrd (the Rerun viewer and CLI expect it)")
    _check_items(items, scene=kwargs.get("scene", False))   # before the file sink opens: bad input leaves no .rrd
    path.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id or path.stem)
    rec.save(path)
    try:
        log_trajectories(rec, items, **kwargs)
        rec.flush()
    finally:
        rec.disconnect()
    return path


def make_blueprint(items: Sequence[Item]) -> rrb.Blueprint:
    """Layout: shared 3-D world and provenance on the left, one column of time series per label on the right."""
    names = _check_items(items)
    per_label = []
    cameras = []
    for name, (_, traj, _) in zip(names, items):
        per_label.append(rrb.Vertical(
            rrb.TimeSeriesView(origin=f"plots/{name}/action", name=f"{name}: actions")
            if traj.policy_action is None else
            rrb.TimeSeriesView(origin=f"plots/{name}",
                               contents=[f"+ plots/{name}/action/**", f"+ plots/{name}/policy_action/**"],
                               name=f"{name}: actions (executed, and the policy's)"),
            rrb.TimeSeriesView(origin=f"plots/{name}",
                               contents=[f"+ plots/{name}/jaw_angle/**", f"+ plots/{name}/flags/**"],
                               name=f"{name}: jaw angle (rad) & device flags"),
            rrb.TimeSeriesView(origin=f"plots/{name}",
                               contents=[f"+ plots/{name}/reward/**", f"+ plots/{name}/success/**"],
                               name=f"{name}: reward & success"),
            name=name))
        cameras += [rrb.Spatial2DView(origin=f"camera/{name}/{cam}", name=f"{name}: {cam}")
                    for cam in sorted(traj.images)]
    left = [rrb.Spatial3DView(origin="world", name="tool-tip paths (all sources)")]
    if cameras:
        left.append(rrb.Tabs(*cameras, name="cameras"))
    left.append(rrb.Tabs(*[rrb.TextDocumentView(origin=f"provenance/{n}", name=f"{n}: provenance")
                           for n in names], name="provenance"))
    return rrb.Blueprint(
        rrb.Horizontal(rrb.Vertical(*left, row_shares=[3] + [2] * (len(left) - 2) + [1]),
                       rrb.Horizontal(*per_label), column_shares=[2, max(1, len(per_label))]),
        collapse_panels=True,
    )


# --------------------------------------------------------------------------------------------------------

def _check_items(items: Sequence[Item], scene: bool = False) -> list[str]:
    if not items:
        raise ValueError("no episodes given; pass a list of (label, Trajectory, provenance) tuples")
    names = []
    for item in items:
        if len(item) != 3 or not isinstance(item[1], Trajectory):
            raise TypeError("each item must be (label: str, trajectory: Trajectory, provenance: dict), "
                            f"got {type(item).__name__} of length {len(item) if hasattr(item, '__len__') else '?'}")
        names.append(entity_label(item[0]))
        missing = [k for k in ("env_id", "seed") if scene and dict(item[2]).get(k) is None]
        if missing:
            raise ValueError(f"scene=True replays each episode: its provenance needs {' and '.join(missing)} "
                             f"({item[0]!r} has none); pass scene=False to log without the scene")
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ValueError(f"episode labels must be unique (after making them path-safe), duplicated: {dup}; "
                         "add the episode index or seed to the label")
    return names


def _timeline(steps: np.ndarray) -> list[rr.TimeColumn]:
    return [rr.TimeColumn("step", sequence=steps),
            rr.TimeColumn("time", duration=steps * CONTROL_PERIOD_S)]


def _shade(color: tuple[int, int, int], arm: int) -> tuple[int, int, int]:
    # Second and further arms of a label: lighter tones of the label colour.
    f = min(0.6, 0.3 * arm)
    return tuple(int(c + (255 - c) * f) for c in color)


def _log_episode(rec: rr.RecordingStream, name: str, label: str, traj: Trajectory, provenance: dict,
                 color: tuple[int, int, int], *, object_position: slice | None,
                 trail_length: int | None, jpeg_quality: int | None,
                 rcm_positions: Sequence[np.ndarray] | None = None, scene: bool = False) -> None:
    T = len(traj)
    states = _timeline(np.arange(T + 1))       # reset state + one per action
    actions = _timeline(np.arange(T))          # a_t at step t
    results = _timeline(np.arange(1, T + 1))   # reward/success of a_t describe state t+1

    tip = np.asarray(traj.tip_position, np.float64)
    if scene:
        _log_scene(rec, name, traj, provenance, states)
    for arm in range(tip.shape[1]):
        base = f"world/{name}/arm{arm}"
        path = tip[:, arm, :]
        c = _shade(color, arm)
        if INTERVENTION in traj.flags and T:   # one segment per step, coloured by who drove the arm
            who = np.asarray(traj.flags[INTERVENTION], bool).reshape(T, -1)[:, arm]
            segments = [path[t:t + 2] for t in range(T)]
            rec.log(f"{base}/path", rr.LineStrips3D(segments, colors=[OPERATOR_COLOUR if w else c for w in who],
                                                    radii=[0.0004]), static=True)
        else:
            rec.log(f"{base}/path", rr.LineStrips3D([path], colors=[c], radii=[0.0004]), static=True)
        starts = np.zeros(T + 1, int) if trail_length is None else np.maximum(0, np.arange(T + 1) - trail_length + 1)
        trails = [path[s:t + 1] for t, s in enumerate(starts)]
        rec.log(f"{base}/trail", rr.LineStrips3D.from_fields(colors=[c], radii=[0.0008]), static=True)
        rec.send_columns(f"{base}/trail", indexes=states,
                         columns=rr.LineStrips3D.columns(strips=trails).partition([1] * (T + 1)))
        rec.log(f"{base}/tip", rr.Points3D.from_fields(colors=[c], radii=[0.0015],
                                                       labels=[f"{label} arm{arm}"]), static=True)
        rec.send_columns(f"{base}/tip", indexes=states,
                         columns=rr.Points3D.columns(positions=path).partition([1] * (T + 1)))
        if rcm_positions is not None and arm < len(rcm_positions) and not scene:
            _log_instrument(rec, base, traj.observation, arm, rcm_positions[arm], c, states)

    obs = np.asarray(traj.observation, np.float64)
    if object_position is not None and obs.shape[1] >= (object_position.stop or 0):
        obj = obs[:, object_position]
        if obj.shape[1] != 3:
            raise ValueError(f"object_position {object_position} selects {obj.shape[1]} columns, expected 3")
        rec.log(f"world/{name}/object", rr.Points3D.from_fields(colors=[(230, 230, 230)], radii=[0.002]),
                static=True)
        rec.send_columns(f"world/{name}/object", indexes=states,
                         columns=rr.Points3D.columns(positions=obj).partition([1] * (T + 1)))

    goal = np.asarray(traj.desired_goal, np.float64)
    if goal.shape[1] % 3 == 0:   # goal = one or more 3-D positions; other goal encodings have no marker
        n_goals = goal.shape[1] // 3
        rec.log(f"world/{name}/goal", rr.Points3D.from_fields(colors=[color] * n_goals, radii=[0.0025],
                                                              labels=[f"{label} goal"] * n_goals), static=True)
        rec.send_columns(f"world/{name}/goal", indexes=states,
                         columns=rr.Points3D.columns(positions=goal.reshape(-1, 3)).partition([n_goals] * (T + 1)))

    act = np.asarray(traj.action, np.float64)
    rec.log(f"plots/{name}/action", rr.SeriesLines(names=_action_names(act.shape[1], tip.shape[1])), static=True)
    rec.send_columns(f"plots/{name}/action", indexes=actions, columns=rr.Scalars.columns(scalars=act))
    if traj.policy_action is not None:
        proposed = np.asarray(traj.policy_action, np.float64)
        rec.log(f"plots/{name}/policy_action",
                rr.SeriesLines(names=[f"policy {n}" for n in _action_names(proposed.shape[1], tip.shape[1])]),
                static=True)
        rec.send_columns(f"plots/{name}/policy_action", indexes=actions,
                         columns=rr.Scalars.columns(scalars=proposed))

    jaw = np.asarray(traj.jaw_angle, np.float64).reshape(T + 1, -1)
    rec.log(f"plots/{name}/jaw_angle", rr.SeriesLines(names=[f"jaw angle arm{i}" for i in range(jaw.shape[1])]),
            static=True)
    rec.send_columns(f"plots/{name}/jaw_angle", indexes=states, columns=rr.Scalars.columns(scalars=jaw))

    flag_names = list(DEVICE_FLAGS) + sorted(set(traj.flags) - set(DEVICE_FLAGS))
    # event flags may have one column per arm (grasped): plotted as "any arm"
    flags = np.stack([np.asarray(traj.flags[f], np.float64).reshape(len(traj), -1).max(axis=1, initial=0.0)
                      for f in flag_names], axis=1)
    # Step-like points, not lines: a flag is an on/off state per step, interpolating between steps would lie.
    rec.log(f"plots/{name}/flags", rr.SeriesPoints(names=flag_names, marker_sizes=[3.0] * len(flag_names)),
            static=True)
    rec.send_columns(f"plots/{name}/flags", indexes=actions, columns=rr.Scalars.columns(scalars=flags))

    rec.log(f"plots/{name}/reward", rr.SeriesLines(names=["reward"]), static=True)
    rec.send_columns(f"plots/{name}/reward", indexes=results,
                     columns=rr.Scalars.columns(scalars=np.asarray(traj.reward, np.float64)))
    rec.log(f"plots/{name}/success", rr.SeriesPoints(names=["success"], marker_sizes=[3.0]), static=True)
    rec.send_columns(f"plots/{name}/success", indexes=results,
                     columns=rr.Scalars.columns(scalars=np.asarray(traj.success, np.float64)))

    for cam, frames in sorted(traj.images.items()):
        _log_camera(rec, f"camera/{name}/{cam}", np.asarray(frames), states, jpeg_quality)

    outcome = trajectory_proficiency(traj).as_dict()
    rec.send_property(label, rr.AnyValues(**_flatten({**provenance, "outcome": outcome})))
    rec.log(f"provenance/{name}", rr.TextDocument(_provenance_markdown(label, provenance, outcome),
                                                 media_type=rr.MediaType.MARKDOWN), static=True)


_INSTRUMENT_GREY = (150, 150, 160)


def _log_scene(rec: rr.RecordingStream, name: str, traj: Trajectory, provenance: dict,
               states: list[rr.TimeColumn]) -> None:
    from surrol_data.viz.scene_meshes import log_scene, replay_scene

    replay = replay_scene(str(provenance["env_id"]), int(provenance["seed"]), traj.action, traj.tip_position)
    log_scene(rec, f"world/{name}/scene", replay, states)
    if replay.notes:
        rec.log(f"world/{name}/scene", rr.TextLog(" ".join(replay.notes), level="WARN"), static=True)


def _log_instrument(rec: rr.RecordingStream, base: str, observation: np.ndarray, arm: int, rcm: np.ndarray,
                    colour: tuple[int, int, int], states: list[rr.TimeColumn]) -> None:
    """Shaft and wrist in steel grey, the blades in the label's colour, four strips per step."""
    from surrol_data.viz.instrument import episode_instrument_strips

    per_step = episode_instrument_strips(observation, arm, rcm)
    rec.log(f"{base}/rcm", rr.Points3D([rcm], colors=[_INSTRUMENT_GREY], radii=[0.0012]), static=True)
    rec.log(f"{base}/instrument", rr.LineStrips3D.from_fields(
        colors=[_INSTRUMENT_GREY, _INSTRUMENT_GREY, colour, colour], radii=[0.0010, 0.0008, 0.0004, 0.0004]),
        static=True)
    rec.send_columns(f"{base}/instrument", indexes=states,
                     columns=rr.LineStrips3D.columns(strips=[s for step in per_step for s in step])
                     .partition([4] * len(per_step)))


def _action_names(act_dim: int, n_arms: int) -> list[str]:
    per_arm = act_dim // n_arms if n_arms and act_dim % n_arms == 0 else 0
    if per_arm == len(ACTION_NAMES):
        if n_arms == 1:
            return list(ACTION_NAMES)
        return [f"{n} arm{a}" for a in range(n_arms) for n in ACTION_NAMES]
    return [f"a{i}" for i in range(act_dim)]   # e.g. ECM actions: no fixed names


def _log_camera(rec: rr.RecordingStream, entity: str, frames: np.ndarray, index: list[rr.TimeColumn],
                jpeg_quality: int | None) -> None:
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise ValueError(f"{entity}: images must be (T+1, H, W, 3) uint8, got {frames.shape} {frames.dtype}")
    n, h, w, _ = frames.shape
    if jpeg_quality is None:
        rec.log(entity, rr.Image.from_fields(format=rr.components.ImageFormat(
            width=w, height=h, color_model="RGB", channel_datatype="U8")), static=True)
        rec.send_columns(entity, indexes=index, columns=rr.Image.columns(buffer=frames.reshape(n, -1)))
        return
    from PIL import Image as PILImage   # only needed for compression; Pillow ships with matplotlib

    blobs = []
    for frame in frames:
        buf = io.BytesIO()
        PILImage.fromarray(frame).save(buf, format="JPEG", quality=int(jpeg_quality))
        blobs.append(buf.getvalue())
    rec.log(entity, rr.EncodedImage.from_fields(media_type="image/jpeg"), static=True)
    rec.send_columns(entity, indexes=index, columns=rr.EncodedImage.columns(blob=blobs))


def _plain(value):
    """A value Rerun's AnyValues accepts: bool/int/float/str or a flat list of them; anything else as text."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)) and value and all(isinstance(v, (bool, int, float, str)) for v in value) \
            and len({type(v) for v in value}) == 1:
        return list(value)
    return str(value)


def _flatten(d: Mapping, prefix: str = "") -> dict:
    out = {}
    for key, value in d.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(_flatten(value, name + "."))
        elif value is not None:   # AnyValues cannot type a None; provenance should not hold any anyway
            out[name] = _plain(value)
    return out


def _provenance_markdown(label: str, provenance: Mapping, outcome: Mapping) -> str:
    lines = [f"# {label}", "", "## Outcome", "",
             f"- success: **{outcome['success']}** (final step: {outcome['final_success']})",
             f"- steps to success: {outcome['steps_to_success']} of {outcome['steps']}",
             f"- path length: {outcome['path_length_cm']:.2f} cm (whole episode {outcome['path_length_full_cm']:.2f} cm)",
             f"- jaw closures: {outcome['jaw_closures']}, clutch uses: {outcome['clutch_uses']}",
             "", "## Provenance", ""]
    flat = _flatten(provenance)
    if flat:
        lines += ["| key | value |", "|---|---|"] + [f"| {k} | {v} |" for k, v in flat.items()]
    else:
        lines.append("(none given)")
    return "\n".join(lines) + "\n"
