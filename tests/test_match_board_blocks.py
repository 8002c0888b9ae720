"""A glyph block's collision shape may be its pixels merged into few boxes (match_board.MERGED_BLOCK_BOXES, in
MatchBoardPanel): the same solid, fewer resting contacts."""

import gymnasium as gym
import numpy as np
import pytest

import surrol_data.envs  # noqa: F401  (registers the ids)
from surrol_data.envs import match_board as mb
from surrol_data.envs.physics import pb


@pytest.mark.parametrize("glyph", sorted(mb.GLYPHS))
def test_a_glyphs_boxes_cover_exactly_its_pixels_once(glyph):
    cells = [(c0 + i, r0 + j) for c0, r0, w, h in mb.glyph_boxes(glyph) for i in range(w) for j in range(h)]
    assert sorted(cells) == sorted(tuple(int(v) for v in p) for p in mb.glyph_pixels(glyph))   # no gap, no overlap
    assert len(mb.glyph_boxes(glyph)) <= 3


@pytest.mark.parametrize("glyph", sorted(mb.GLYPHS))
def test_merged_boxes_bound_the_same_solid_as_the_pixel_boxes(glyph):
    """Every point of the merged boxes lies in a pixel box and the other way round (box centres and corners)."""
    shapes = {}
    for merged in (False, True):
        halves, centres = mb._block_boxes(glyph, merged)
        shapes[merged] = [(np.asarray(c), np.asarray(h)) for h, c in zip(halves, centres)]

    def inside(point, boxes):
        return any(np.all(np.abs(point - c) <= h + 1e-9) for c, h in boxes)

    for a, b in ((True, False), (False, True)):
        for c, h in shapes[a]:
            for corner in np.array(np.meshgrid(*[[-1, 0, 1]] * 3)).T.reshape(-1, 3):
                assert inside(c + corner * h, shapes[b])


def test_a_block_resting_in_the_drawer_keeps_few_contact_points():
    """MatchBoardPanel's placed block: one 4-point manifold per child box on the drawer floor (32 points with a box
    per pixel, each solved at every physics step)."""
    env = gym.make("SurRoL/MatchBoardPanel-v0")
    u = env.unwrapped
    obs, info = env.reset(seed=0)
    while not info["is_success"]:
        obs, _, _, truncated, info = env.step(u.oracle_action(obs))
        assert not truncated
    for _ in range(5):
        obs, *_ = env.step(u.oracle_action(obs))
    points = pb.getContactPoints(bodyA=u.object_id, physicsClientId=u.client._client)
    assert 0 < len(points) <= 4 * len(mb.glyph_boxes(u.glyph))
    env.close()
