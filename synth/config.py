"""The dataset configuration: one frozen section per component, all defaults here.

A preset (``configs/data/*.yaml``) lists only what differs; the command line overrides
single keys (``rig.overlap=0.3 camera.width=160``). The resolved config is written
into the dataset manifest, and its hash identifies a dataset (the sweep reuses a
render whose resolved config hash matches).

Example::

    cfg = load_data_config("configs/data/tiny.yaml", ["seed=3", "rig.overlap=0.5"])
"""
from __future__ import annotations

from typing import Iterable, Literal

from pydantic import Field, model_validator

from scenes.config import SceneConfig
from corelib.configlib import ConfigError, StrictModel, added_key, load_config
from synth.rig import CameraConfig, RigConfig
from synth.sensor import SensorConfig
from synth.weather import WeatherConfig


class DatasetConfig(StrictModel):
    """How many sequences, how long, and how they are split."""

    sequences: int = Field(24, ge=1, le=100000)
    frames: int = Field(20, ge=3, le=10000, description="frames per sequence")
    fps: float = Field(10.0, gt=0.5, le=100.0)
    val_fraction: float = Field(0.125, ge=0.0, lt=1.0)
    test_fraction: float = Field(0.125, ge=0.0, lt=1.0)

    @model_validator(mode="after")
    def _check_split(self) -> "DatasetConfig":
        if self.val_fraction + self.test_fraction >= 1.0:
            raise ValueError("dataset.val_fraction + dataset.test_fraction must be < 1")
        return self


class LightingConfig(StrictModel):
    """Lighting variation: per sequence (time of day), per camera (exposure, white balance), per frame (flicker)."""

    times_of_day: list[Literal["morning", "noon", "afternoon", "dusk", "overcast"]] = Field(
        default_factory=lambda: ["morning", "noon", "afternoon", "dusk", "overcast"])
    exposure_sigma: float = Field(0.15, ge=0.0, le=1.0, description="log-normal sigma of per-camera gain")
    white_balance_sigma: float = Field(0.05, ge=0.0, le=0.5, description="per-channel log-normal sigma")
    flicker_sigma: float = Field(0.02, ge=0.0, le=0.2, description="per-frame per-camera gain jitter")
    shadows: bool = True

    @model_validator(mode="after")
    def _nonempty(self) -> "LightingConfig":
        if not self.times_of_day:
            raise ValueError("lighting.times_of_day must name at least one of morning, noon, afternoon, dusk, overcast")
        return self


class EgoConfig(StrictModel):
    """How the ego car's body (what the rig sees of its own car: the self-occlusion regions) looks.

    ``appearance``: ``static`` (the default, and every render before the key) shades the body like the world,
    diffuse paint under the sequence's fixed sun: on a straight road it looks the same in every frame (but for
    the gain flicker and a passing shadow), so Monodepth2's auto-masking can hide it and training without the
    ego masks may cost little, where the paper measured a large cost on DDAD (abs_rel 0.220 with the masks,
    0.358 without). ``live`` makes the paint and the glass a clear coat that reflects the world around the car
    as it moves and turns, as on a real car: per frame (per camera time), the scene without the ego is rendered
    into a cube of ``reflection_px`` px faces above the roof, and each ego fragment mixes its diffuse colour
    with the cube's colour along its mirrored view ray by Schlick's Fresnel term (F0 = 0.04, strong at the
    grazing angles the side cameras see the roof at), plus the sun's highlight, both darkened by the shadow
    map (shadows of passing objects move over it as before). The reflection normal leans towards a curved
    body's, so the roof mirrors the horizon band where the world passes, not only the sky. Only the RGB of ego
    pixels changes: depth, masks and labels are the static render's (`synth.gl_backend`;
    tests/synth/test_ego_live.py). ``reflection_px``: the side of each cube face; the cost is six extra small
    renders per frame (benchmarks/ego_costs.py: 1.6x the renderer's CPU time at 96x64; docs/DATASET.md).
    """

    appearance: Literal["static", "live"] = "static"
    reflection_px: int = Field(64, ge=8, le=1024, description="cube-face side of the live reflection (pixels)")


class RenderConfig(StrictModel):
    backend: Literal["auto", "egl", "osmesa"] = "auto"
    shadow_map_size: int = Field(2048, ge=256, le=8192)
    png_compression: int = Field(3, ge=0, le=9)


class LabelsConfig(StrictModel):
    """Which ground-truth labels a render writes besides RGB and depth (`synth.labels`). Defaults by cost
    (docs/results/render_throughput.md, 320x192): semantic and instance maps add about 8 % render time each
    and 12-18 KB a rig-frame; forward flow adds about 40 % time and about 0.8 MB a rig-frame (two float32
    channels), so it is off unless asked for (``labels.flow=true``)."""

    semantic: bool = Field(True, description="<frame>.semantic.png: a class index per pixel (manifest labels.classes)")
    instance: bool = Field(True, description="<frame>.instance.png (16-bit object ids) and <seq>/instances.json")
    flow: bool = Field(False, description="<frame>.flow.exr forward flow t -> t+1 in pixels, its validity and "
                       "the moving-object mask")
    # an added key (issue 50): off, a render writes what it wrote before it existed, and every hash stays
    mesh: bool = added_key(False, description="<seq>/world_mesh.npz: the world mesh as rendered, so a viewer "
                           "(synth view, mcdp predict --rrd) shows it without the generator config")


class DataConfig(StrictModel):
    """Everything that defines a dataset. Same config + seed -> same bytes on the same back end."""

    seed: int = Field(0, ge=0, le=2**31 - 1)
    rig: RigConfig = Field(default_factory=RigConfig)
    camera: CameraConfig = Field(default_factory=CameraConfig)
    dataset: DatasetConfig = Field(default_factory=DatasetConfig)
    scene: SceneConfig = Field(default_factory=SceneConfig)
    lighting: LightingConfig = Field(default_factory=LightingConfig)
    render: RenderConfig = Field(default_factory=RenderConfig)
    # an added key: images and depth are those rendered without it, so every dataset's hash stays (a dataset
    # rendered before the labels says what it lacks when a command needs them)
    labels: LabelsConfig = added_key(default_factory=LabelsConfig)
    # added keys (issue 48): off, the written image is the renderer's; on, only the RGB changes (the sensor
    # acts on the formed image, `synth.sensor`; fog from the exact depth, `synth.weather`)
    sensor: SensorConfig = added_key(default_factory=SensorConfig)
    weather: WeatherConfig = added_key(default_factory=WeatherConfig)
    # an added key (issue 57, item 6): static, the ego body is rendered as before and every hash stays
    ego: EgoConfig = added_key(default_factory=EgoConfig)

    @model_validator(mode="after")
    def _rolling_flow(self) -> "DataConfig":
        if self.sensor.rolling_shutter_ms > 0 and self.labels.flow:
            raise ValueError("labels.flow cannot go with sensor.rolling_shutter_ms > 0: a rolling-shutter image has "
                             "one camera pose per band of rows, and forward flow takes one (synth.shutter)")
        return self


def load_data_config(path=None, overrides: Iterable[str] = ()) -> DataConfig:
    return load_config(DataConfig, path, overrides)


#: the largest render `synth render` (and `mcdp sweep` / `mcdp pretrain`, all their renders together) starts
#: without ``--yes`` (bytes, the upper bound of `render_size`)
MAX_RENDER_BYTES = 500 * 10**9
_BYTES_PER_PIXEL = 3 + 4  # RGB uint8 + float32 z-depth, before PNG / EXR compression (about 2 measured)


def bytes_per_pixel(cfg: DataConfig) -> int:
    """Uncompressed bytes a render of `cfg` writes per pixel: RGB, depth and the labels it asks for (each label
    kind's cost: `synth.label_kinds`)."""
    from synth.label_kinds import label_bytes_per_pixel

    return _BYTES_PER_PIXEL + label_bytes_per_pixel(cfg.labels)


def render_size(cfg: DataConfig, shard_of: int = 1) -> dict:
    """What a render writes: rig frames, images and an upper bound of its bytes (images uncompressed, each
    camera at its own size; the tiny preset's files measured about 2 bytes a pixel). ``shard_of`` N: one of N
    shards."""
    from synth.rig import camera_sizes_of

    sizes = camera_sizes_of(cfg.rig, cfg.camera)
    rig_frames = -(-cfg.dataset.sequences // shard_of) * cfg.dataset.frames
    images = rig_frames * len(sizes)
    pixels = sum(w * h for w, h in sizes.values())  # of one rig frame
    out = {"rig_frames": rig_frames, "images": images, "max_bytes": rig_frames * pixels * bytes_per_pixel(cfg)}
    from synth.shutter import Shutter

    shutter = Shutter.for_config(cfg)
    if shutter is not None and shutter.renders_per_image() > 1:  # the render's time, multiplied (`size_statement`)
        out["renders"] = images * shutter.renders_per_image()
    return out


def total_render_size(sizes) -> dict:
    """The sum of several `render_size` results (a sweep's worlds); ``renders`` when the shutter of any takes
    more than one render an image."""
    sizes = list(sizes)
    out = {k: sum(s[k] for s in sizes) for k in ("rig_frames", "images", "max_bytes")}
    if any("renders" in s for s in sizes):
        out["renders"] = sum(s.get("renders", s["images"]) for s in sizes)
    return out


def size_statement(size: dict, what: str = "") -> str:
    """One line: the rig-frames, images and bytes of a render (`render_size`), said before it starts; when the
    shutter (motion blur, rolling shutter: `synth.shutter`) takes several renders an image, how many, and so
    about how many times longer the render takes than one of still images."""
    line = (f"{size['rig_frames']} rig-frames, {size['images']} images{what} (RGB, depth and labels): "
            f"{size['max_bytes'] / 1e9:.3g} GB before compression, about a third of that on disk")
    renders = size.get("renders", size["images"])
    if renders > size["images"]:
        each = renders / max(1, size["images"])
        line += (f"; the shutter (sensor.subframes x sensor.rolling_bands) takes {each:.3g} renders an image, "
                 f"{renders} in all, so its rendering takes up to {each:.3g} times as long as with still images")
    return line


def empty_split_warning(splits: dict[str, list], sequences: int) -> str | None:
    """One line when a split of the render will be empty (too few ``dataset.sequences`` for the fractions):
    ``mcdp train`` then validates nothing and ``mcdp eval`` / ``predict`` refuse that split. None when none is."""
    empty = [k for k, v in splits.items() if not v]
    if not empty:
        return None
    return (f"warning: {sequences} sequence(s) leave the {' and '.join(empty)} split(s) empty (no validation loss "
            "in mcdp train; mcdp eval / predict refuse an empty split); raise dataset.sequences (3 or more) or "
            "dataset.val_fraction / test_fraction")


def check_render_size(size: dict, yes: bool, source: str, keys: str = "dataset.sequences / dataset.frames / "
                      "camera.*") -> None:
    """ConfigError naming `source` when a render (or all of a command's renders) is above `MAX_RENDER_BYTES`
    and the user did not say ``--yes``."""
    if size["max_bytes"] > MAX_RENDER_BYTES and not yes:
        raise ConfigError(f"{source}: this render is up to {size['max_bytes'] / 1e9:.3g} GB, more than "
                          f"{MAX_RENDER_BYTES / 1e9:.0f} GB; lower {keys} or pass --yes")
