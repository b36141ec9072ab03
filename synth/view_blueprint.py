"""The Rerun blueprint (the viewer's layout) of `synth view` and `mcdp predict --rrd` recordings.

Left: one 3-D view of ``world`` (the rig's frusta and RGB, the world mesh, the ego trajectory, the
ground-truth and predicted points). Right: tabs, each a grid of the six cameras laid out like the car
(front row left to right, back row as seen from behind it; `ring_order`):

- **RGB**: each camera's image; its depth, ego mask and overlap mask are in the view but hidden
  (toggle them with the eye icon in the blueprint panel), so no mask covers the image by default;
- **depth (ground truth)**: the depth images; the masks hidden the same way;
- **depth <stage>** (`mcdp predict --rrd` only, one tab per stage): the predicted depth, its abs_rel
  image hidden;
- **labels** (`synth view` of a dataset with labels): the image under its class map and the forward flow's
  arrows (`synth.view_labels`); the other tabs and the 3-D view hide both.

The 3-D view starts behind and above the car of the first frame; the selection and time
panels start collapsed (the blueprint panel, with the toggles, open). It hides the per-camera depth and mask images (a depth image under a pinhole would be drawn
as a second point cloud there). Entity paths: `synth.view`'s module docstring.
"""
from __future__ import annotations

import math

import numpy as np


def ring_order(cameras) -> tuple[list[str], int]:
    """(camera names in grid order, columns): the cameras looking forward (|yaw| <= 90°) left to right, then
    those looking back, left to right as seen from behind the car (yaw from the optical axis in the ego frame:
    x forward, y left)."""
    yaw = {}
    for cam in cameras:
        z = np.asarray(cam.T_ego_cam, np.float64)[:3, 2]
        yaw[cam.name] = math.degrees(math.atan2(z[1], z[0]))
    front = sorted((n for n, a in yaw.items() if abs(a) <= 90.0), key=lambda n: -yaw[n])
    back = sorted((n for n in yaw if n not in front), key=lambda n: yaw[n] % 360.0)
    return front + back, max(len(front), len(back), 1)


def _hide(rrb, paths) -> dict:
    return {p: rrb.EntityBehavior(visible=False) for p in paths}


#: where the 3-D view's eye starts, in the ego frame of the first frame: behind and above the car, looking ahead
EYE_EGO_M, TARGET_EGO_M = (-16.0, 0.0, 9.0), (8.0, 0.0, 0.0)


def short(name: str) -> str:
    """A camera's view title: its name without the "CAM_" prefix (the grid's cells are narrow)."""
    return name[4:] if name.startswith("CAM_") else name


def eye(rrb, T_world_ego) -> object:
    """The 3-D view's eye: behind and above the ego at `T_world_ego` (the first frame's pose), looking ahead."""
    T = np.asarray(T_world_ego, np.float64)

    def at(p):
        return (T[:3, :3] @ np.asarray(p) + T[:3, 3]).tolist()

    return rrb.EyeControls3D(position=at(EYE_EGO_M), look_target=at(TARGET_EGO_M), eye_up=[0.0, 0.0, 1.0])


def rig_blueprint(rrb, cameras, cam_path, stages=(), T_world_ego=None, labels: tuple[str, ...] = ()) -> object:
    """The blueprint (module docstring) for `cameras` (`synth.rig` cameras), whose entities sit under
    ``cam_path(name)``; `stages`: the predicted stages with a tab each; `T_world_ego`: the first frame's ego pose
    (the 3-D view starts behind the car), or None for Rerun's own view of everything; `labels`: the label entities
    of a labels tab (`synth.label_kinds`: the kinds that log themselves), () for none."""
    names, cols = ring_order(cameras)
    masks = ("ego_mask", "overlap", *labels)

    def grid(title, shown, hidden, name_suffix=""):
        views = []
        for n in names:
            o = cam_path(n)
            views.append(rrb.Spatial2DView(origin=o, name=f"{short(n)}{name_suffix}",
                                           contents=[f"$origin/{p}" for p in (*shown, *hidden)],
                                           overrides=_hide(rrb, [f"{o}/{p}" for p in hidden])))
        return rrb.Grid(*views, grid_columns=cols, name=title)

    tabs = [grid("RGB", ["rgb"], ["depth", *masks]), grid("depth (ground truth)", ["depth"], list(masks), " depth")]
    for s in stages:
        tabs.append(grid(f"depth {s}", [f"pred/{s}/depth"], [f"pred/{s}/abs_rel", *masks], f" {s}"))
    if labels:
        tabs.append(grid("labels", ["rgb", *labels], ["depth", "ego_mask", "overlap"], " labels"))
    hidden_3d = [f"{cam_path(n)}/{p}" for n in names for p in ("depth", *masks, "pred")]
    world = rrb.Spatial3DView(origin="world", name="world: rig, mesh, trajectory, points",
                              overrides=_hide(rrb, hidden_3d),
                              eye_controls=None if T_world_ego is None else eye(rrb, T_world_ego))
    return rrb.Blueprint(rrb.Horizontal(world, rrb.Tabs(*tabs), column_shares=[2, 3]),
                         rrb.SelectionPanel(state="collapsed"), rrb.TimePanel(state="collapsed"))
