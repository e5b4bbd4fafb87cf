"""Beyond Blocks: the candidate families, the everyday catalog, and real grasps of real objects."""
from __future__ import annotations

import subprocess
import sys
from collections import Counter

import numpy as np
import pytest

from rsb_maniskill.objects import catalog, geometry
from rsb_maniskill.objects import family as fam
from rsb_maniskill.objects.family import BlockFamily, ObjectFamily, get_family
from rsb_maniskill.objects.layout import CELL_MARGIN
from rsb_maniskill.semantic import EpisodeSampler


def test_catalog_has_24_categories_with_variants():
    assert len(catalog.CATEGORY_KEYS) >= 24
    assert len(catalog.MODEL_KEYS) == len(catalog.CATEGORY_KEYS) * catalog.NUM_VARIANTS
    names = [catalog.category_name(c) for c in catalog.CATEGORY_KEYS]
    assert len(set(names)) == len(names), "instruction names must tell the categories apart"
    for cat in catalog.CATEGORY_KEYS:
        models = [catalog.model(f"{cat}:{v}") for v in range(catalog.NUM_VARIANTS)]
        colours = {tuple(p.rgb) for m in models for p in m.parts[:2]}
        sizes = {round(m.height, 4) for m in models} | {m.half_extents for m in models}
        assert len(colours) >= 2 and len(sizes) >= 2, f"{cat}: variants must differ in colour and size"


@pytest.mark.parametrize("key", catalog.MODEL_KEYS)
def test_every_model_rests_fits_and_can_be_grasped(key):
    m = catalog.model(key)
    layout = ObjectFamily.layout
    cx, cy = layout.pitch[0] / 2 - CELL_MARGIN, layout.pitch[1] / 2 - CELL_MARGIN
    assert m.half_extents[0] <= cx and m.half_extents[1] <= cy, f"{key} does not fit a layout cell"
    assert m.height <= catalog.MAX_HEIGHT
    pts = np.concatenate([geometry.part_points(p) for p in m.parts if p.collide])
    assert abs(pts[:, 2].min()) < 2e-3, "rests on its bottom"
    assert m.grasps, "at least one grasp frame"
    for g in m.grasps:
        assert g.width <= catalog.MAX_GRASP_WIDTH
        assert m.height - g.pos[2] <= catalog.MAX_ABOVE_TCP, "the fingers' base clears the top"
        assert g.pos[2] >= catalog.MIN_TCP_Z, "the fingertips stay above the table"
    assert catalog.model(key) is m, "built once per process"


def test_unknown_object_key_is_clear():
    with pytest.raises(KeyError, match="mug:0"):
        catalog.model("mug:7")
    with pytest.raises(ValueError, match="valid: blocks, objects"):
        get_family("lego")


def test_registry_lists_both_families_with_their_suffixes():
    import rsb_maniskill.objects as objects

    assert fam.target_names() == objects.TARGETS == fam.TARGETS == ("blocks", "objects")
    assert {n: f.suffix for n, f in fam.FAMILIES.items()} == {"blocks": "", "objects": "-Objects"}
    assert fam.OBJECTS_SUFFIX == "-Objects"
    assert fam.split_env_id("rsb_maniskill:RSB-Math-4-Objects") == ("RSB-Math-4", "objects")
    assert fam.split_env_id("RSB-Math-4") == ("RSB-Math-4", "blocks")
    assert fam.join_env_id("RSB-Math-4", "objects") == "RSB-Math-4-Objects"
    assert fam.family_of_keys(["block:red", "block:F"]) == "blocks"
    assert fam.family_of_keys(["mug:2", "apple:0"]) == "objects"
    with pytest.raises(ValueError, match="no candidate family"):
        fam.family_of_keys(["block:red", "mug:2"])
    assert fam.get_family("blocks").builder.endswith(":build_block")
    assert fam.get_family("objects").builder.endswith(":build_object")
    with pytest.raises(ValueError, match="clashes"):
        fam.register_family(ObjectFamily())


def test_a_new_family_is_one_registration():
    class Toys(BlockFamily):
        name, suffix = "toys", "-Toys"
        builder = "rsb_maniskill.objects.blocks:build_block"

        def owns(self, key):
            return key.startswith("toy:")

    fam.register_family(Toys())
    try:
        assert fam.split_env_id("RSB-Math-4-Toys") == ("RSB-Math-4", "toys")
        assert isinstance(get_family("toys"), Toys) and "toys" in fam.TARGETS
        assert fam.family_of_keys(["toy:1"]) == "toys"
        assert fam.split_env_id("RSB-Math-4-Objects") == ("RSB-Math-4", "objects")
    finally:
        fam.unregister_family("toys")
    assert fam.target_names() == ("blocks", "objects")
    assert fam.split_env_id("RSB-Math-4-Toys") == ("RSB-Math-4-Toys", "blocks")
    with pytest.raises(ValueError, match="unknown targets 'toys'"):
        get_family("toys")


def test_block_family_is_the_old_blocks():
    f = BlockFamily()
    assert f.draw(4, "ABCD").names == ("red block", "green block", "blue block", "yellow block")
    letters = tuple("ABCDEFGHIK")
    drawn = f.draw(10, letters)
    assert drawn.names[5] == "block F" and drawn.keys[5] == "block:F"
    assert f.lettered(10) and not f.lettered(4)


def test_every_category_is_the_target_equally_often():
    s = EpisodeSampler("RSB-Math-4", "test", targets="objects")
    targets = Counter()
    for seed in range(4800):
        sp = s.episode(seed)
        assert len({c.split(":")[0] for c in sp.candidates}) == 4
        targets[sp.candidates[sp.target_block].split(":")[0]] += 1
    assert set(targets) == set(catalog.CATEGORY_KEYS)
    expected = 4800 / len(catalog.CATEGORY_KEYS)
    chi2 = sum((c - expected) ** 2 / expected for c in targets.values())
    assert chi2 < 50, f"target categories far from uniform (chi2 {chi2:.1f}, df 23): {targets}"


def test_objects_change_names_not_questions():
    blocks = EpisodeSampler("RSB-Math-10", "test")
    objects = EpisodeSampler("RSB-Math-10", "test", targets="objects")
    for seed in range(20):
        a, b = blocks.episode(seed), objects.episode(seed)
        assert (a.question, a.options, a.answer_slot) == (b.question, b.options, b.answer_slot)
        assert all(name in b.instruction for name in b.block_names), "every object is named"
        assert " block" not in b.instruction


def test_hull_meshes_are_cached_and_atomic(tmp_path, monkeypatch):
    from rsb_maniskill.objects.everyday import hull_file

    monkeypatch.setenv("RSB_CACHE_DIR", str(tmp_path))
    pts = geometry.frustum(0.02, 0.03, 0.05)
    a = hull_file(pts)
    mtime = (tmp_path / "meshes").stat().st_mtime_ns
    assert hull_file(pts) == a and a.startswith(str(tmp_path))
    assert sorted(p.suffix for p in (tmp_path / "meshes").iterdir()) == [".obj"], "no temporary file left"
    assert (tmp_path / "meshes").stat().st_mtime_ns == mtime


def test_family_imports_without_the_simulator():
    code = ("import sys; import rsb_maniskill.objects.family as f; f.get_family('objects').draw(4, 'ABCD', "
            "__import__('numpy').random.default_rng(0)); "
            "bad = [m for m in ('sapien', 'torch', 'mani_skill', 'trimesh') if m in sys.modules]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)


# ---------------------------------------------------------------- physics: real grasps of real objects
def _seed_with_target(suite: str, category: str, arm: str) -> int:
    """First test-split seed whose target is ``category`` on the ``arm`` side (y >= 0: left)."""
    import gymnasium as gym

    s = EpisodeSampler(suite, "test", targets="objects")
    env = gym.make(suite + "-Objects", obs_mode="state", render_backend="none", split="test")
    for seed in range(400):
        sp = s.episode(seed)
        if sp.candidates[sp.target_block].split(":")[0] != category:
            continue
        env.reset(seed=seed)
        y = float(env.unwrapped.candidate_actor(sp.target_block).pose.p[0, 1])
        if (y >= 0) == (arm == "left"):
            env.close()
            return seed
    raise AssertionError(f"no seed with a {category} target on the {arm} side")


@pytest.mark.parametrize("category, arm", [("mug", "left"), ("banana", "right"), ("tennis_ball", "left"),
                                           ("toy_car", "right"), ("bowl", "right"), ("spray_bottle", "left")])
def test_expert_lifts_and_places_real_objects(category, arm):
    import gymnasium as gym

    from rsb_maniskill.motionplan import ScriptedExpert

    seed = _seed_with_target("RSB-Math-4", category, arm)
    env = gym.make("RSB-Math-4-Objects", obs_mode="state", render_backend="none", split="test")
    env.reset(seed=seed)
    u = env.unwrapped
    target = int(u.target_block[0])
    res = ScriptedExpert(env).run()
    info = u.get_info()
    assert res.success and res.arm == arm, res
    assert info["grasped_correct"].item() and not info["grasped_wrong"].item()
    assert info["first_grasped"].item() == target and info["placed_correct"].item()
    pos = u.pool.raw_poses()[0, target, :3]
    assert abs(float(pos[2]) - float(u.rest_z[0, target])) < 0.005, "placed upright, at rest on the table"
    env.close()


def test_picking_the_wrong_object_is_a_wrong_grasp():
    import gymnasium as gym

    from rsb_maniskill.motionplan import ScriptedExpert

    env = gym.make("RSB-Math-10-Objects", obs_mode="state", render_backend="none", split="test")
    env.reset(seed=3)
    u = env.unwrapped
    wrong = (int(u.target_block[0]) + 1) % 10
    res = ScriptedExpert(env, target_block=wrong).run()
    info = u.get_info()
    assert not res.success and res.reason == "wrong_block"
    assert info["grasped_wrong"].item() and info["first_grasped"].item() == wrong
    assert info["placed_wrong"].item() and info["fail"].item()
    env.close()


def test_parked_objects_sleep_out_of_sight_and_out_of_contact():
    """CPU: pool members not in play hang asleep and hidden under the table, whatever the robot
    does and across resets, so they cost no simulation, contacts or rendering."""
    import gymnasium as gym
    import sapien

    env = gym.make("RSB-Math-10-Objects", obs_mode="state", render_backend="none")
    u = env.unwrapped
    for seed in (0, 1):
        env.reset(seed=seed)
        for _ in range(20):
            env.step(u.agent.rest_action()[None] + 0.05)
        parked = [k for k in range(len(u.pool.keys)) if k not in u.pool.index[0].tolist()]
        assert len(parked) == len(u.pool.keys) - 10
        assert all(u.pool.actors[k]._bodies[0].is_sleeping for k in parked)
        assert all(float(u.pool.actors[k].pose.p[0, 2]) < -0.2 for k in parked), "under the table top"
        parked_bodies = {u.pool.actors[k]._bodies[0].entity for k in parked}
        touching = [c for c in u.scene.px.get_contacts() if {b.entity for b in c.bodies} & parked_bodies]
        assert not touching
        for k in parked:
            for obj in u.pool.actors[k]._objs:
                body = obj.find_component_by_type(sapien.render.RenderBodyComponent)
                assert body is None or body.visibility == 0
    env.close()
