"""A fragment behind the camera never reaches the depth map: the regression case found in the L_con sweep's
world 10 (docs/results/lcon.md), where one pixel of sequence 45, CAM_BACK_RIGHT, frame 3 came out at -24.06 m.

llvmpipe rasterised one fragment of a triangle there whose interpolated camera z was negative; the fragment
shader writes ``gl_FragDepth = z / zfar``, which the depth buffer clamps to 0, so that fragment won the depth
test against the true surface at 24.19 m. The main fragment shader now discards any fragment with z <= 0 (it
cannot be visible), and every other pixel of the render is unchanged."""
from pathlib import Path

import numpy as np

from corelib.configlib import load_config

TINY = Path(__file__).resolve().parents[2] / "configs" / "data" / "tiny.yaml"
# world 10 of configs/sweep/cpu_lcon.yaml at overlap 0.10, its calibrated rig given as the solved angle
WORLD_10 = ["seed=10", "dataset.sequences=88", "dataset.frames=10", "dataset.val_fraction=0.0909",
            "dataset.test_fraction=0.3636", "rig.overlap=0.165313", "rig.overlap_target=angle",
            "labels.semantic=false", "labels.instance=false"]


def test_the_world_10_pixel_is_the_surface_behind_it_not_a_negative_depth():
    from synth.config import DataConfig
    from synth.gl_backend import LightState
    from synth.pipeline import build_sequence_scene
    from synth.render import make_ego_mesh, make_rig, renderer_for

    cfg = load_config(DataConfig, TINY, WORLD_10)
    rig, scene = make_rig(cfg), build_sequence_scene(cfg, 45)
    cam = rig.cameras[rig.names.index("CAM_BACK_RIGHT")]
    r = renderer_for(cfg)
    r.load_scene(scene, make_ego_mesh(cfg))
    light = LightState((0.3, 0.2, 0.9), (1, 1, 1), (0.3, 0.3, 0.3), (0.5, 0.6, 0.8), (0.7, 0.7, 0.8), shadows=False)
    depth = r.render(cam.K, scene.T_world_ego[3] @ cam.T_ego_cam, 3, light, size=(cam.width, cam.height))["depth"]
    assert (depth >= 0).all(), np.argwhere(depth < 0).tolist()  # 0 = sky; was -24.06 at (15, 83)
    around = np.concatenate([depth[14:17, 82], depth[14:17, 84], depth[[14, 16], 83]])
    assert 23.5 < depth[15, 83] < 25.0 and abs(depth[15, 83] - np.median(around)) < 0.5, depth[13:18, 81:86]
