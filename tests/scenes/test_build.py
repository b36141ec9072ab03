"""build_scene: every family, determinism, ego poses, keep-out, movers, validation."""
import json
from pathlib import Path

import numpy as np
import pytest

from scenes import FAMILIES, SceneConfig, build_scene, pick_family
from scenes.model import Mesh, Mover, Scene
from scenes.polyline import distance_to_polyline
from scenes.world import KEEPOUT_M, KEEPOUT_Z_M, MOVER_CLEARANCE_M

ROOT = Path(__file__).resolve().parents[2]
SPEED = {"urban": (6.0, 12.0), "residential": (6.0, 12.0), "highway": (18.0, 28.0)}
N_FRAMES, FPS = 12, 10.0
CASES = [(fam, seed) for fam in FAMILIES for seed in (0, 1)]  # include straight and turning routes


def _build(fam, seed, **kw):
    cfg = SceneConfig(family=fam, texture_size=128, **kw)
    return build_scene(cfg, N_FRAMES, FPS, np.random.default_rng(seed))


@pytest.fixture(scope="module")
def scenes():
    # turn_probability 0.5 by default: seeds 0-2 give both straight and turning routes
    return {(fam, seed): _build(fam, seed) for fam, seed in CASES}


@pytest.mark.parametrize("fam,seed", CASES)
def test_scene_basics(scenes, fam, seed):
    sc = scenes[(fam, seed)]
    assert sc.family == fam and sc.info["family"] == fam
    assert sc.T_world_ego.shape == (N_FRAMES, 4, 4) and sc.T_world_ego.dtype == np.float64
    assert 1000 < sc.static.n_triangles < 60000
    assert sc.info["n_triangles"] == sc.static.n_triangles
    assert sc.info["n_movers"] == len(sc.movers)
    json.dumps(sc.info)
    assert sc.textures.shape[1:] == (128, 128, 3)
    assert int(sc.static.layers.max()) < len(sc.materials)
    np.testing.assert_allclose(np.linalg.norm(sc.static.normals, axis=1), 1.0, atol=1e-4)


@pytest.mark.parametrize("fam,seed", CASES)
def test_ego_poses(scenes, fam, seed):
    sc = scenes[(fam, seed)]
    T = sc.T_world_ego
    R = T[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-9)
    np.testing.assert_allclose(T[:, :3, 2], np.tile([0, 0, 1.0], (N_FRAMES, 1)), atol=1e-9)  # z up
    np.testing.assert_allclose(T[:, 2, 3], 0.0)
    np.testing.assert_allclose(T[:, 3], np.tile([0, 0, 0, 1.0], (N_FRAMES, 1)))
    step = np.diff(T[:, :2, 3], axis=0)
    speed = np.linalg.norm(step, axis=1) * FPS
    lo, hi = SPEED[fam]
    assert np.all(speed > lo - 0.05) and np.all(speed < hi + 0.05)
    assert np.isclose(speed.mean(), sc.info["speed_mps"], rtol=0.02)
    # heading follows the route: ego x axis along the direction of motion
    fwd = 0.5 * (T[:-1, :2, 0] + T[1:, :2, 0])
    cos = np.sum(fwd * step, axis=1) / (np.linalg.norm(fwd, axis=1) * np.linalg.norm(step, axis=1))
    assert np.all(cos > 0.995)


def test_some_routes_turn(scenes):
    turns = {fam: [scenes[(fam, s)].info["turn"] for s in (0, 1)] for fam in FAMILIES}
    assert any(any(v) for v in turns.values()) and any(not all(v) for v in turns.values())
    cfg = SceneConfig(family="urban", turn_probability=1.0, texture_size=128)
    sc = build_scene(cfg, 60, 10.0, np.random.default_rng(5))
    yaw = np.unwrap(np.arctan2(sc.T_world_ego[:, 1, 0], sc.T_world_ego[:, 0, 0]))
    assert sc.info["turn"] and np.ptp(yaw) > 0.3


@pytest.mark.parametrize("fam,seed", CASES)
def test_keepout_static(scenes, fam, seed):
    sc = scenes[(fam, seed)]
    p = sc.static.positions.astype(np.float64)
    high = p[p[:, 2] > KEEPOUT_Z_M, :2]
    ego = sc.T_world_ego[:, :2, 3]
    d = np.min(np.linalg.norm(high[:, None] - ego[None], axis=-1), axis=1)
    assert d.min() > KEEPOUT_M
    # also along the driven path between poses
    assert distance_to_polyline(high, ego).min() > KEEPOUT_M


@pytest.mark.parametrize("fam,seed", CASES)
def test_movers_clear_of_ego_and_each_other(scenes, fam, seed):
    sc = scenes[(fam, seed)]
    ego = sc.T_world_ego[:, :2, 3]
    for m in sc.movers:
        assert m.T_world_obj.shape == (N_FRAMES, 4, 4)
        assert np.linalg.norm(m.T_world_obj[:, :2, 3] - ego, axis=1).min() >= MOVER_CLEARANCE_M
    # car footprints ~4.5 x 1.8 m: centres of two cars must stay > 2 m apart laterally or > 4.6 m overall
    pos = np.stack([m.T_world_obj[:, :2, 3] for m in sc.movers]) if sc.movers else np.zeros((0, N_FRAMES, 2))
    for i in range(len(pos)):
        for j in range(i + 1, len(pos)):
            assert np.linalg.norm(pos[i] - pos[j], axis=-1).min() > 3.0


def test_traffic_present():
    sc = _build("highway", 3, traffic_density=2.0)
    assert len(sc.movers) >= 3
    sc0 = _build("urban", 3, traffic_density=0.0)
    assert sc0.movers == []


def test_determinism(scenes):
    a = scenes[("urban", 0)]
    b = _build("urban", 0)
    for name in ("positions", "normals", "uvs", "layers", "tints", "indices"):
        assert np.array_equal(getattr(a.static, name), getattr(b.static, name))
    assert np.array_equal(a.T_world_ego, b.T_world_ego)
    assert np.array_equal(a.textures, b.textures)
    assert a.info == b.info
    assert len(a.movers) == len(b.movers)
    for ma, mb in zip(a.movers, b.movers):
        assert np.array_equal(ma.T_world_obj, mb.T_world_obj)
        assert np.array_equal(ma.mesh.tints, mb.mesh.tints)
    c = scenes[("urban", 1)]
    assert a.static.n_vertices != c.static.n_vertices or not np.array_equal(a.static.positions, c.static.positions)
    assert not np.array_equal(a.T_world_ego, c.T_world_ego)


def test_mixed_draws_families():
    fams = {pick_family(SceneConfig(), np.random.default_rng(s)) for s in range(12)}
    assert fams == set(FAMILIES)
    only = {pick_family(SceneConfig(family_weights={"urban": 0.0, "residential": 0.0}), np.random.default_rng(s))
            for s in range(5)}
    assert only == {"highway"}  # a family left out keeps its default weight (1)
    old = {pick_family(SceneConfig(family_weights=(0.0, 0.0, 1.0)), np.random.default_rng(s)) for s in range(5)}
    assert old == {"highway"}  # the positional list of old configs and manifests
    assert pick_family(SceneConfig(family="urban"), np.random.default_rng(0)) == "urban"
    sc = build_scene(SceneConfig(texture_size=128, family_weights={"urban": 0, "residential": 1, "highway": 0}), 2,
                     10.0, np.random.default_rng(0))
    assert sc.family == "residential"


def test_build_scene_input_checks():
    cfg = SceneConfig()
    with pytest.raises(ValueError, match="n_frames"):
        build_scene(cfg, 0, 10.0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="fps"):
        build_scene(cfg, 5, 0.0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="rng"):
        build_scene(cfg, 5, 10.0, 0)
    with pytest.raises(ValueError, match="cfg"):
        build_scene({"family": "urban"}, 5, 10.0, np.random.default_rng(0))


def test_model_validation():
    m = Mesh.empty()
    z = np.zeros
    with pytest.raises(ValueError, match="normals"):
        Mesh(z((3, 3)), z((2, 3)), z((3, 2)), z(3, np.int32), z((3, 3)), z((1, 3), np.uint32))
    with pytest.raises(ValueError, match="indices"):
        Mesh(z((3, 3)), z((3, 3)), z((3, 2)), z(3, np.int32), z((3, 3)), np.array([[0, 1, 3]], np.uint32))
    tex = np.zeros((1, 4, 4, 3), np.uint8)
    with pytest.raises(ValueError, match="textures"):
        Scene(m, [], np.zeros((1, 4, 4), np.uint8), ["a"], np.tile(np.eye(4), (2, 1, 1)), "urban")
    with pytest.raises(ValueError, match="materials"):
        Scene(m, [], tex, ["a", "b"], np.tile(np.eye(4), (2, 1, 1)), "urban")
    with pytest.raises(ValueError, match="T_world_ego"):
        Scene(m, [], tex, ["a"], np.eye(4), "urban")
    with pytest.raises(ValueError, match="mover"):
        Scene(m, [Mover("x", m, np.tile(np.eye(4), (3, 1, 1)))], tex, ["a"], np.tile(np.eye(4), (2, 1, 1)), "urban")


def test_config_validation():
    from corelib.configlib import ConfigError, build_config
    with pytest.raises(ConfigError, match="traffic_density"):
        build_config(SceneConfig, {"traffic_density": 9.0})
    with pytest.raises(ConfigError, match="family"):
        build_config(SceneConfig, {"family": "desert"})
    with pytest.raises(ConfigError, match="texture_size"):
        build_config(SceneConfig, {"texture_size": 100})
    for bad, said in (([0, 0, 0], "must not all be 0"), ({"urban": 0, "residential": 0, "highway": 0}, "must not all be 0"),
                      ({"desert": 1.0}, "family_weights.desert: unknown scene family"),
                      ({"urban": -1.0}, r"family_weights.urban must be in \[0, 1000\]"),
                      ({"highway": float("nan")}, "family_weights.highway must be"), ([1, 2], "3 numbers, got 2")):
        with pytest.raises(ConfigError, match=said):
            build_config(SceneConfig, {"family_weights": bad})


def test_family_weights_are_a_mapping_hashed_as_the_positional_list_of_old():
    """{urban: 1, residential: 1, highway: 1}, filled in from the defaults, in the draw's order; every dataset
    rendered when it was a list keeps its hash (tiny.yaml's, pinned), whichever form a preset writes."""
    from corelib.configlib import config_hash, config_to_dict, load_config
    from synth.config import DataConfig

    tiny = ROOT / "configs" / "data" / "tiny.yaml"
    cfg = load_config(DataConfig, tiny)
    assert config_to_dict(cfg)["scene"]["family_weights"] == {"urban": 1.0, "residential": 1.0, "highway": 1.0}
    assert config_hash(cfg) == "4c93be54b2f0ddb35c56d70e7fd2b087d4a0e648eeb11eb99ebc6a5727a1c9d8"  # before the mapping
    assert config_hash(load_config(DataConfig, tiny, ["scene.family_weights=[1,1,1]"])) == config_hash(cfg)
    part = load_config(DataConfig, tiny, ["scene.family_weights.highway=0"])
    assert list(part.scene.family_weights.items()) == [("urban", 1.0), ("residential", 1.0), ("highway", 0.0)]
    assert config_hash(part) == config_hash(load_config(DataConfig, tiny, ["scene.family_weights=[1,1,0]"])) \
        != config_hash(cfg)
    for w in ((1.0, 1.0, 1.0), (0.0, 2.0, 1.0), (0.5, 0.0, 0.0)):  # the same draw as the tuple's, seed by seed
        sc = SceneConfig(family_weights=dict(zip(FAMILIES, w)))
        p = np.asarray(w) / sum(w)
        assert [pick_family(sc, np.random.default_rng(s)) for s in range(40)] == \
            [FAMILIES[int(np.random.default_rng(s).choice(3, p=p))] for s in range(40)]


def test_every_family_has_one_builder():
    from scenes.config import FAMILIES
    from scenes.families import BUILDERS

    assert tuple(BUILDERS) == FAMILIES
