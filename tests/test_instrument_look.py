"""What the surgeon sees of the instruments, by pixels: jaws that open and close on screen, shadows that give depth.

Every task is rendered by its own endoscope. On the PSM tasks (eleven of the fifteen) the first arm's jaw is put
open and then closed (the tool roll turned so the opening faces the camera), and the segmentation image of
Panda3D and of TinyRenderer must show the two blades' tips apart when open (a pixel between them that is not the
tool) and joined when closed (the closed blades cover the open tips' midpoint). With the tool tip 1 cm above the
surface under it, switching the shadow light's shadows on must darken at least 2 % of the Panda3D image. The tool
is brought to the centre of the view first (tasks start with it at the view's edge).

The four ECM tasks show no instrument (the endoscope is the robot; no jaw test applies), so what carries depth there
is the objects in view: the blocks of MisOrient, StaticTrack and ActiveTrack must cast shadows onto the floor they
stand on, and ECMReach's only object, its translucent goal marker, is a cue for the eye rather than a thing in the
cavity and must cast none.

The instrument is shaded as a solid of its shape: the shaft reads round (brighter and darker across its width), which
TinyRenderer's own tessellation of a primitive cannot show (its normals point from the primitive's centre, so a
long cylinder is lit the same across its width).

Panda3D cases skip (naming the Debian packages) where it cannot open an offscreen OpenGL buffer.
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import surrol_data.envs  # noqa: F401
from surrol_data.envs import TASKS, env_id
from surrol_data.envs import kinematics as kin
from surrol_data.envs.camera import camera_axes, make_camera, pixel_of, project
from surrol_data.envs.units import SCALING
from surrol_data.render.display import unavailable_reason
from surrol_data.render.env_view import EnvEndoscope

SIZE = (320, 240)
SHADOW_SIZE = (160, 120)
JAW_OPEN = np.deg2rad(60.0)
SHADOW_SHARE = 0.02        # of the image darkened by shadows (issue 29)
DARKER = 10                # luminance levels (of 255) that count as a shadow
ROLLS = np.deg2rad(np.arange(-150.0, 151.0, 30.0))

needs_panda3d = pytest.mark.skipif(unavailable_reason() is not None, reason=str(unavailable_reason()))


def psms_of(env) -> list:
    u = env.unwrapped
    return list(getattr(u, "psms", None) or ([u.psm] if getattr(u, "psm", None) is not None else []))


ECM_TASKS = ("ECMReach", "MisOrient", "StaticTrack", "ActiveTrack")
PSM_TASKS = [t for t in TASKS if t not in ECM_TASKS]
BLOCK_SHADOW_SHARE = 0.003   # of the image: the contact shadows of blocks standing on the floor (0.6–0.9 % measured)


def blade_tips(psm) -> list[np.ndarray]:
    """World points (real metres) 9 mm along each blade from the yaw axis."""
    tips = []
    for link in (6, 7):
        pos, rot = psm.link_pose_world(link)
        tips.append(pos + rot @ np.array([0.0, 0.009, 0.0]))
    return tips


def tip_pixels(psm, pose) -> list[np.ndarray]:
    axes = camera_axes(pose)
    return [np.array(pixel_of(project(axes, p, SIZE[0] / SIZE[1])[:2], *SIZE)) for p in blade_tips(psm)]


def hover_in_view(psm, client, pose, scene_scale: float, height_m: float) -> None:
    """Put the tool tip ``height_m`` above the surface at the centre of the view (the tip's orientation kept)."""
    axes = camera_axes(pose)
    start = np.asarray(axes.eye) * scene_scale
    end = (np.asarray(axes.eye) + np.asarray(axes.forward)) * scene_scale
    hit = client.rayTest(start.tolist(), end.tolist())[0]
    assert hit[0] >= 0, "nothing at the centre of the view"
    target = psm.tip_pose()
    target[:3, 3] = np.asarray(hit[3]) / scene_scale + [0.0, 0.0, height_m]
    result = psm.ik(target)
    assert result.within_limits, "the centre of the view is out of the arm's reach"
    psm.reset_joints(result.q, 0.0)


def face_the_camera(psm, pose) -> np.ndarray:
    """Joint values with the jaw's opening turned across the view (the roll whose open tips lie farthest apart)."""
    q = psm.joint_positions()
    best, best_q = -1.0, q
    for roll in ROLLS:
        trial = q.copy()
        trial[3] = np.clip(roll, kin.PSM_LOWER[3], kin.PSM_UPPER[3])
        psm.reset_joints(trial, JAW_OPEN)
        a, b = tip_pixels(psm, pose)
        if np.linalg.norm(a - b) > best:
            best, best_q = float(np.linalg.norm(a - b)), trial
    return best_q


def line(a, b, n: int = 40) -> np.ndarray:
    return np.round(np.linspace(a, b, n)).astype(int)


def on_tool(seg: np.ndarray, body: int, pixel, reach: int = 1) -> bool:
    c, r = int(pixel[0]), int(pixel[1])
    window = seg[max(0, r - reach):r + reach + 1, max(0, c - reach):c + reach + 1]
    return bool((window == body).any())


@pytest.mark.parametrize("renderer", ["tiny", pytest.param("panda3d", marks=needs_panda3d)])
@pytest.mark.parametrize("task", PSM_TASKS)
def test_the_jaws_open_apart_and_close_together_on_screen(task, renderer):
    env = gym.make(env_id(task), render_mode="rgb_array")
    try:
        env.reset(seed=0)
        view = EnvEndoscope(env)
        pose = view.pose()
        camera = make_camera(view.client, SIZE, view.scene_scale, renderer)
        psm = psms_of(env)[0]
        hover_in_view(psm, view.client, pose, view.scene_scale, height_m=0.015)
        q = face_the_camera(psm, pose)
        psm.reset_joints(q, JAW_OPEN)
        a, b = tip_pixels(psm, pose)
        assert np.linalg.norm(a - b) >= 5, f"the open tips are {np.linalg.norm(a - b):.1f} px apart: too far to see"
        seg = camera.render(pose, segmentation=True).segmentation
        assert on_tool(seg, psm.body, a) and on_tool(seg, psm.body, b), "both blade tips must be drawn"
        gap = [p for p in line(a, b) if not on_tool(seg, psm.body, p, reach=0)]
        assert gap, "open jaws: no pixel between the blade tips is free of the tool"
        # Closed, the blades lie along the bisector of the open ones, through the open tips' midpoint.
        psm.reset_joints(q, 0.0)
        seg = camera.render(pose, segmentation=True).segmentation
        assert on_tool(seg, psm.body, (a + b) / 2), "closed jaws: the blades do not meet between the open tips"
        if hasattr(camera, "close"):
            camera.close()
    finally:
        env.close()


def luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb.astype(np.float64) @ np.array([0.299, 0.587, 0.114])


@needs_panda3d
@pytest.mark.parametrize("task", TASKS)
def test_shadows_darken_a_visible_share_of_the_image(task):
    """PSM tasks: with the tool hovering 1 cm above the surface; ECM tasks: the objects as the task shows them."""
    env = gym.make(env_id(task), render_mode="rgb_array")
    try:
        env.reset(seed=0)
        view = EnvEndoscope(env)
        pose = view.pose()
        if task in PSM_TASKS:
            hover_in_view(psms_of(env)[0], view.client, pose, view.scene_scale, height_m=0.01)
        share = shadow_share(view, pose)
        if task == "ECMReach":   # the goal marker alone: a cue, no shadow
            assert share < 0.001, f"the goal marker casts a shadow over {share:.2%} of the image"
        else:
            least = SHADOW_SHARE if task in PSM_TASKS else BLOCK_SHADOW_SHARE
            assert share >= least, f"shadows darken {share:.2%} of the image"
    finally:
        env.close()


def shadow_share(view, pose) -> float:
    """The share of the Panda3D image that switching the shadows on darkens (and a check that they only darken)."""
    from surrol_data.render.panda_camera import PandaEndoscopeCamera

    images = []
    for shadows in (True, False):
        cam = PandaEndoscopeCamera(view.client, SHADOW_SIZE, view.scene_scale, shadows=shadows)
        images.append(luminance(cam.render(pose).rgb))
        cam.close()
    darker = images[1] - images[0]
    assert (darker < -2).mean() < 0.001, "a shadow only takes light away"
    return float((darker > DARKER).mean())


NEEDLE_SIZE = (640, 480)
STRIPES = 5.0    # luminance levels (of 255) off the local mean along the arc: 14 striped, under 2 smooth (measured)


def needle_profile(renderer: str) -> np.ndarray:
    """NeedlePick's needle seen by ``renderer``: the brightest needle pixel near each of 200 points along its arc
    (the highlight running along the wire), from the blunt end to the point."""
    from surrol_data.envs import objects

    env = gym.make(env_id("NeedlePick"), render_mode="rgb_array")
    try:
        env.reset(seed=0)
        view = EnvEndoscope(env)
        pose = view.pose()
        camera = make_camera(view.client, NEEDLE_SIZE, view.scene_scale, renderer)
        image = camera.render(pose, segmentation=True)
        if hasattr(camera, "close"):
            camera.close()
        body = env.unwrapped.object_id
        origin, rot = objects.needle_pose(view.client, body)
        lum = luminance(image.rgb)
        axes, aspect = camera_axes(pose), NEEDLE_SIZE[0] / NEEDLE_SIZE[1]
        profile = []
        for angle in np.linspace(np.pi / 2, 3 * np.pi / 2, 200)[5:-5]:   # the ends' caps left out
            point = origin + rot @ (objects.NEEDLE_RADIUS * np.array([np.cos(angle), np.sin(angle), 0.0]))
            c, r = (int(round(v)) for v in pixel_of(project(axes, point, aspect)[:2], *NEEDLE_SIZE))
            window = (slice(max(0, r - 2), r + 3), slice(max(0, c - 2), c + 3))
            on_needle = image.segmentation[window] == body
            assert on_needle.any(), f"the needle is not drawn at {angle:.2f} rad of its arc ({renderer})"
            profile.append(lum[window][on_needle].max())
        return np.array(profile)
    finally:
        env.close()


@pytest.mark.parametrize("renderer", ["tiny", pytest.param("panda3d", marks=needs_panda3d)])
def test_the_needle_is_shaded_smoothly_along_its_arc(renderer):
    """No stripes: along the arc the needle's highlight changes slowly (light and view turn with the arc), not
    bright–dark every few millimetres. TinyRenderer once drew it striped: it shades a primitive by normals from the
    primitive's centre, which along a chain of thin capsules point along the wire."""
    profile = needle_profile(renderer)
    local_mean = np.convolve(profile, np.ones(15) / 15, mode="valid")
    ripple = np.abs(profile[7:-7] - local_mean)
    assert ripple.mean() < STRIPES, f"the needle's shading ripples by {ripple.mean():.0f} levels along its arc"


def test_the_needle_mesh_file_is_what_the_geometry_makes():
    from surrol_data.envs import instrument_geometry, objects

    made = instrument_geometry.needle_obj_text(objects.NEEDLE_RADIUS, objects.NEEDLE_WIRE_RADIUS)
    assert instrument_geometry.NEEDLE_MESH_FILE.read_text() == made, \
        "envs/meshes/needle.obj is stale: remake it with instrument_geometry.write_needle_mesh(" \
        "objects.NEEDLE_RADIUS, objects.NEEDLE_WIRE_RADIUS)"


def test_the_instrument_mesh_files_are_what_the_geometry_makes():
    from surrol_data.envs import instrument_geometry

    made = instrument_geometry.instrument_obj_texts()
    stale = [path.name for path, text in made.items() if not path.is_file() or path.read_text() != text]
    assert not stale, f"envs/meshes/{stale[0]} is stale: remake it with instrument_geometry.write_instrument_meshes()"
    on_disk = {p.name for p in instrument_geometry.MESH_DIR.glob("*.obj")} - {instrument_geometry.NEEDLE_MESH_FILE.name}
    assert on_disk == {p.name for p in made}, "envs/meshes holds instrument meshes the geometry no longer makes"


def test_the_instruments_visual_shapes_are_the_meshes_with_their_colours():
    """What PyBullet hands back to the Panda3D mirror and to Rerun: each tool link's visual shapes are the piece's
    OBJ meshes (one per colour), at the scene's scale, in the link's frame."""
    from surrol_data.envs import instrument_geometry
    from surrol_data.envs.physics import pb

    env = gym.make(env_id("NeedlePick"), render_mode="rgb_array")
    try:
        env.reset(seed=0)
        psm = psms_of(env)[0]
        shapes = env.unwrapped.client.getVisualShapeData(psm.body)
        for link, piece in ((3, "shaft"), (4, "wrist"), (6, "jaw_plus"), (7, "jaw_minus")):
            got = [(s[2], s[4].decode(), tuple(np.round(s[3], 6)), tuple(np.round(s[7], 3)))
                   for s in shapes if s[1] == link]
            want = [(pb.GEOM_MESH, str(path), (SCALING,) * 3, tuple(np.round(colour, 3)))
                    for path, colour in instrument_geometry.piece_mesh_files(piece)]
            assert got == want, f"link {link} ({piece}): {got}"
    finally:
        env.close()


SHAFT_ROUND = 5.0   # luminance levels (of 255) across the shaft's width: 0 with centre normals, 11–70 round (measured)


@pytest.mark.parametrize("renderer", ["tiny", pytest.param("panda3d", marks=needs_panda3d)])
def test_the_shaft_is_shaded_round_across_its_width(renderer):
    """Across the black shaft, 2–4 cm above the wrist, the luminance varies as over a cylinder (light falling on it
    from the scope's side); a shaft drawn with normals along its axis is one flat tone across."""
    size = (640, 480)
    env = gym.make(env_id("NeedlePick"), render_mode="rgb_array")
    try:
        env.reset(seed=0)
        view = EnvEndoscope(env)
        pose = view.pose()
        psm = psms_of(env)[0]
        hover_in_view(psm, view.client, pose, view.scene_scale, height_m=0.015)
        camera = make_camera(view.client, size, view.scene_scale, renderer)
        image = camera.render(pose, segmentation=True)
        if hasattr(camera, "close"):
            camera.close()
        lum = luminance(image.rgb)
        axes, aspect = camera_axes(pose), size[0] / size[1]
        pos, rot = psm.link_pose_world(3)   # tool roll: z along the shaft towards the tip
        ranges = []
        for d in (0.02, 0.03, 0.04):
            a, b = (np.array(pixel_of(project(axes, pos + rot @ [0.0, 0.0, -z], aspect)[:2], *size))
                    for z in (d, d + 0.001))
            along = (b - a) / np.linalg.norm(b - a)
            across = np.array([-along[1], along[0]])
            values = []
            for t in np.arange(-15.0, 15.5, 0.5):
                c, r = np.round(a + t * across).astype(int)
                if 0 <= r < size[1] and 0 <= c < size[0] and image.segmentation[r, c] == psm.body \
                        and lum[r, c] < 90:   # the black shaft, not the steel or the scene behind
                    values.append(lum[r, c])
            assert len(values) >= 6, f"the shaft is {len(values)} samples wide {100 * d:.0f} cm above the wrist"
            ranges.append(float(np.ptp(values)))
        assert min(ranges) >= SHAFT_ROUND, f"across the shaft the luminance varies by {ranges} levels: it looks flat"
    finally:
        env.close()


def test_the_instrument_has_the_endowrists_sizes():
    """The meshes as drawn (read back from their files, as the Panda3D mirror and Rerun read them): the shaft is
    8 mm across, and each jaw blade reaches the tool tip (``kinematics.TIP_LENGTH`` from the yaw axis)."""
    from surrol_data.envs import instrument_geometry
    from surrol_data.render.body_shapes import obj_mesh

    shaft = obj_mesh(str(instrument_geometry.MESH_DIR / "shaft_black.obj")).positions
    assert np.hypot(shaft[:, 0], shaft[:, 1]).max() == pytest.approx(0.004, abs=1e-6)
    assert np.ptp(shaft[:, 2]) > 0.3   # the shaft runs out of view, up to the RCM and beyond
    for piece in ("jaw_plus", "jaw_minus"):
        blade = np.concatenate([obj_mesh(str(path)).positions
                                for path, _ in instrument_geometry.piece_mesh_files(piece)])
        assert blade[:, 1].max() == pytest.approx(kin.TIP_LENGTH, abs=1e-6), piece
