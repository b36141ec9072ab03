"""The `synth` command: render, verify, preview, merge, export and view datasets (`COMMANDS`).

Examples::

    synth render configs/data/tiny.yaml --out data/tiny rig.overlap=0.3 --workers 2
    synth render configs/data/default.yaml --out data/def --shard 0/4   # one of four deterministic shards
    synth render configs/data/tiny.yaml --print-config rig.overlap=0.3  # the resolved config; nothing rendered
    synth presets                                                       # the data presets in configs/data
    synth info data/tiny [--json]                                       # sequences, splits, overlap, size
    synth verify data/tiny
    synth preview data/tiny --out sheet.png
    synth merge --out data/full shard0 shard1
    synth export data/tiny --format nuscenes --out data/tiny_ns [--version v1.0-synth] [lidar.azimuth_res_deg=0.4]
    synth export data/tiny --format gltf --out data/tiny_gltf          # the viz extra: .venv-viz/bin/synth
    synth view data/tiny --seq seq_00000 --frames 0:4 --out rig.rrd    # Rerun recording; .venv-viz/bin/synth
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from corelib.cli import Command
from corelib.presets import complete_presets


def _render_args(r: argparse.ArgumentParser) -> None:
    complete_presets(r.add_argument("config", help="preset YAML, e.g. configs/data/tiny.yaml (list: synth presets); "
                                    "then key=value overrides, e.g. rig.overlap=0.3 seed=2"), "data")
    r.add_argument("--out", help="output dataset folder (new, empty, or a partial render to resume); required "
                   "unless --print-config")
    r.add_argument("--print-config", action="store_true", help="print the resolved config (YAML, overrides "
                   "applied) on stdout and exit 0; nothing is rendered or written")
    r.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    r.add_argument("--shard", default=None, help="K/N: render only sequences with index %% N == K")
    r.add_argument("--engine", default="local", choices=["local", "ray"], help="local: --workers processes; ray: one Ray task per sequence on a local Ray "
                   "(the machine's cores) or the cluster at RAY_ADDRESS (pip install -e '.[cluster]'; docs/SCALING.md)")
    r.add_argument("--no-progress", action="store_true", help="no progress bar (log lines only)")
    r.add_argument("--yes", action="store_true", help="start a render larger than synth.config.MAX_RENDER_BYTES "
                   "(500 GB uncompressed) without refusing")
    r.set_defaults(overrides=[])


def _info_args(i: argparse.ArgumentParser) -> None:
    i.add_argument("data", help="finished synth dataset folder (or a nuScenes dataroot)")
    i.add_argument("--json", action="store_true", help="the summary as JSON")


def _info(args) -> int:
    from synth.info import dataset_info, format_info

    info = dataset_info(args.data)
    print(json.dumps(info, indent=1) if args.json else format_info(info))
    return 0


def _presets(args) -> int:
    from corelib.presets import format_presets

    print(format_presets(["data"]))
    return 0


def _verify_args(v: argparse.ArgumentParser) -> None:
    v.add_argument("data", help="synth dataset folder (a nuScenes dataroot is named as one, its tables loaded)")


def _preview_args(pv: argparse.ArgumentParser) -> None:
    pv.add_argument("data", help="finished synth dataset folder")
    pv.add_argument("--out", required=True, help="PNG file to write")
    pv.add_argument("--sequence", "--seq", dest="sequence", default=None, help="sequence id (default: the first); "
                    "--seq as in synth view")
    pv.add_argument("--frame", type=int, default=0, help="frame index in the sequence (default 0)")


def _preview(args) -> int:
    from synth.open import open_dataset
    from synth.preview import make_preview

    print(f"wrote {make_preview(open_dataset(args.data), args.out, args.sequence, args.frame)}")
    return 0


def _merge_args(m: argparse.ArgumentParser) -> None:
    m.add_argument("shards", nargs="+", help="shard folders rendered with one config (synth render --shard K/N)")
    m.add_argument("--out", required=True, help="merged dataset folder (new, empty, or an earlier merge of these "
                   "shards: a rerun adds what is new)")


def _outside_datasets(out: str) -> None:
    from corelib.configlib import ConfigError
    from synth.dataset import dataset_containing

    inside = dataset_containing(out)
    if inside is not None:
        raise ConfigError(f"--out {out} is inside the dataset {inside}; nothing was written: write outside it")


def _merge(args) -> int:
    from corelib.text import bounded
    from synth.merge import merge_datasets, merge_statement

    _outside_datasets(args.out)

    res = merge_datasets([Path(s) for s in args.shards], Path(args.out))
    print(bounded(merge_statement(res, Path(args.out))), file=sys.stdout if res["complete"] else sys.stderr)
    return 0 if res["complete"] else 1


def _export_args(e: argparse.ArgumentParser) -> None:
    e.add_argument("data", help="finished synth dataset folder")
    e.add_argument("--format", required=True, choices=["nuscenes", "gltf"],
                   help="nuscenes: a nuScenes dataroot; gltf: per sequence the world and movers as GLB + poses JSON "
                        "(docs/DATASET.md, 'glTF export'; needs the viz extra: .venv-viz/bin/synth, made by "
                        "scripts/setup.sh --test)")
    e.add_argument("--out", required=True, help="dataroot to write (new, empty, or a previous export of this dataset)")
    e.add_argument("--version", default="v1.0-synth", help="table folder name (NuScenes(version=...)); "
                   "default v1.0-synth")
    e.add_argument("--no-lidar", action="store_true", help="cameras only, no synthetic LIDAR_TOP")
    e.add_argument("--no-labels", action="store_true", help="leave the dataset's labels out (no lidarseg, no label "
                   "side files; docs/NUSCENES.md, 'Labels')")
    e.add_argument("--jpeg-quality", type=int, default=None, help="JPEG quality of the nuScenes images, 1..100 "
                   "(default: a JPEG dataset's images copied as they are, a PNG dataset's encoded at 95)")
    e.add_argument("--no-progress", action="store_true", help="no progress bar")
    e.set_defaults(overrides=[])


def _view_args(w: argparse.ArgumentParser) -> None:
    w.add_argument("data", help="finished synth dataset folder (or a nuScenes dataroot)")
    w.add_argument("--out", required=True, help="recording to write, *.rrd (new, or a recording written before)")
    w.add_argument("--seq", "--sequence", dest="seq", default=None, help="sequence id (default: the first); "
                   "--sequence as in synth preview")
    w.add_argument("--frames", default=None, help="A:B, frames A..B-1 (default: all)")
    w.add_argument("--point-stride", type=int, default=2, help="every k-th pixel row and column in the point "
                   "cloud (default 2)")


def _view(args) -> int:
    from synth.view import record_rig

    _outside_datasets(args.out)

    s = record_rig(args.data, args.out, args.seq, args.frames, args.point_stride)
    print(f"wrote {s['out']}: {s['sequence']} frames {s['frames'][0]}:{s['frames'][1]}, {s['bytes'] / 1e6:.2f} MB "
          f"({s['bytes_per_rig_frame'] / 1e6:.3f} MB per rig-frame) in {s['seconds']:.1f} s; open it with "
          f"`rerun {s['out']}`")
    return 0


def main(argv: list[str] | None = None) -> int:
    from corelib import cli, exitcodes
    from corelib.configlib import ConfigError
    from synth.files import DatasetError, OutputFolderError
    from synth.gl_context import RenderBackendError
    from synth.nuscenes.layout import ExportError

    rules = [((ConfigError, DatasetError, OutputFolderError, ExportError, ValueError), exitcodes.USAGE, "error"),
             ((RenderBackendError,), exitcodes.NO_BACKEND, "error"),
             ((RuntimeError,), exitcodes.FAILED, "error")]
    return cli.main("synth", "Synthetic surround-view driving datasets.", COMMANDS, argv, rules)


def _render(args) -> int:
    from corelib.configlib import ConfigError
    from corelib.presets import preset_path
    from synth.config import check_render_size, empty_split_warning, load_data_config, render_size, size_statement
    from synth.dataset import dataset_containing
    from synth.render import assign_splits, parse_shard, render_dataset
    from synth.rig import camera_sizes_of, sizes_text

    cfg = load_data_config(preset_path(args.config, "data"), args.overrides)
    if args.print_config:
        import yaml

        from corelib.configlib import config_to_dict

        print(yaml.safe_dump(config_to_dict(cfg), sort_keys=False), end="")
        return 0
    if args.out is None:
        raise ConfigError("the following arguments are required: --out")
    shard = parse_shard(args.shard)
    inside = dataset_containing(args.out)
    if inside is not None:
        raise ConfigError(f"--out {args.out} is inside the dataset {inside}; nothing was written: render outside it")
    if args.engine == "ray":  # refused before anything is said or written
        from corelib.cluster import import_ray

        import_ray()
    size = render_size(cfg, shard[1])
    print(f"synth render: {size_statement(size, f' of {sizes_text(camera_sizes_of(cfg.rig, cfg.camera))}')}",
          file=sys.stderr)
    check_render_size(size, args.yes, args.config)
    warning = empty_split_warning(assign_splits(cfg), cfg.dataset.sequences)
    if warning:
        print(f"synth render: {warning}", file=sys.stderr)
    s = render_dataset(cfg, args.out, workers=args.workers, shard=shard, engine=args.engine,
                       progress=not args.no_progress)
    print(f"rendered {s['rendered_sequences']} sequence(s) ({s['rig_frames']} rig-frames) in {s['seconds']:.1f} s "
          f"= {s['rig_frames_per_s']:.2f} rig-frames/s on {s['backend']}; skipped {s['skipped_sequences']} complete")
    if s["complete"]:
        ov = s["overlap"]
        print(f"dataset complete: {args.out}  splits {s['splits']}  families {s['families']}")
        print(f"overlap target {ov['target']:.2f} ({ov['mode']}, hfov {ov['hfov_deg']:.1f} deg, "
              f"yaw spacing {ov['yaw_spacing_deg']:.1f} deg); measured pixel overlap per pair:")
        for pair, d in ov["per_pair_measured"].items():
            print(f"  {pair:32s} geometric {d['target']:+.3f}  measured {d['measured']:.3f}")
    else:
        print(f"shard done; the manifest is written once every sequence of {args.out} is complete")
    return 0


def _export(args) -> int:
    """key=value overrides after `export` set the LiDAR model: lidar.KEY=VALUE (synth.lidar.LidarConfig)."""
    from corelib.configlib import ConfigError, build_config, parse_overrides
    from synth.lidar import LidarConfig
    from synth.dataset import dataset_containing
    from synth.nuscenes.export import export_nuscenes
    from synth.open import open_dataset

    if dataset_containing(args.out) is not None:
        raise ConfigError(f"--out {args.out} is inside the dataset {dataset_containing(args.out)}; export outside it")
    ov = parse_overrides(args.overrides)
    unknown = sorted(k for k in ov if k != "lidar")
    if unknown:
        raise ConfigError(f"export overrides must be lidar.KEY=VALUE, got {', '.join(unknown)}")
    if args.no_lidar and ov:
        raise ConfigError("--no-lidar and lidar.* overrides together")
    lidar = None if args.no_lidar else build_config(LidarConfig, ov.get("lidar", {}),
                                                    "lidar overrides " + " ".join(args.overrides))
    s = export_nuscenes(open_dataset(args.data), args.out, version=args.version, lidar=lidar, jpeg_quality=args.jpeg_quality,
                        progress=not args.no_progress and sys.stderr.isatty(), labels=not args.no_labels)
    pts = "" if s["lidar_points_per_sweep"] is None else f", {s['lidar_points_per_sweep']:.0f} lidar points/sweep"
    pts += f", lidarseg for {s['lidarseg']} sweeps" if s["lidarseg"] else ""
    print(f"exported {s['scenes']} scene(s), {s['samples']} samples, {s['sample_data']} sample_data{pts} to "
          f"{s['out']} (NuScenes(version={s['version']!r}, dataroot={s['out']!r}))")
    return 0


def _export_gltf(args) -> int:
    from corelib.configlib import ConfigError
    from synth.gltf_export import export_gltf

    if args.overrides or args.no_lidar or args.version != "v1.0-synth":
        raise ConfigError("--format gltf takes no lidar.* overrides, --no-lidar or --version")
    s = export_gltf(args.data, args.out, progress=not args.no_progress and sys.stderr.isatty())
    print(f"exported {s['sequences']} sequence(s) as glTF ({s['vertices']} vertices, {s['bytes'] / 1e6:.2f} MB) to "
          f"{s['out']}")
    return 0


def _verify(args) -> int:
    from synth.verify import verify_dataset

    from corelib.text import bounded

    from synth.nuscenes.tables import is_nuscenes_root

    if is_nuscenes_root(args.data):  # no manifest: not "manifest.json: missing", but what a dataroot can be checked for
        from synth.verify import verify_nuscenes

        problems, summary = verify_nuscenes(args.data)
        for p in problems:
            print(f"FAIL {bounded(p)}", file=sys.stderr)
        if problems:
            print(f"synth verify: {len(problems)} problem(s) in {bounded(args.data)}, a nuScenes dataroot",
                  file=sys.stderr)
            return 1
        print(f"OK {bounded(args.data)}: {summary}")
        return 0
    problems = verify_dataset(args.data, progress=sys.stderr.isatty())
    if problems:
        for p in problems:
            print(f"FAIL {bounded(p)}", file=sys.stderr)  # a name of the dataset's, escaped
        print(f"synth verify: {len(problems)} problem(s) in {bounded(args.data)}", file=sys.stderr)
        return 1
    from synth.files import read_json
    m = read_json(Path(args.data) / "manifest.json")
    print(f"OK {args.data}: schema v{m['schema_version']}, {len(m['sequences'])} sequences, "
          f"{len(m['files'])} files verified")
    return 0


#: the subcommands, in the one CLI style of `synth` and `mcdp` (`corelib.cli`)
COMMANDS = [
    Command("render", "render a dataset from a preset (+ key=value overrides): per camera and frame RGB, depth and "
            "the ego mask, and labels (semantic class and instance id maps by default; forward flow and the mover "
            "mask with labels.flow=true; none with labels.semantic=false labels.instance=false; docs/DATASET.md)",
            _render_args, _render),
    Command("info", "summary of a dataset: sequences, frames, splits, families, overlap per pair, image size, "
            "disk size", _info_args, _info),
    Command("presets", "list the data presets in configs/data", lambda p: None, _presets),
    Command("verify", "check a dataset's integrity and contract; non-zero exit on any problem", _verify_args, _verify),
    Command("preview", "contact sheet: 6 cameras x (RGB, depth, mask, overlap[, classes, flow])", _preview_args,
            _preview),
    Command("merge", "merge shard folders rendered with one config into one dataset", _merge_args, _merge),
    Command("export", "write a dataset in another format (nuScenes dataroot: docs/NUSCENES.md; glTF)", _export_args,
            lambda args: _export(args) if args.format == "nuscenes" else _export_gltf(args)),
    Command("view", "Rerun recording (.rrd) of a sequence: rig, images, depth, masks, points "
            "(the viz extra: .venv-viz/bin/synth, made by scripts/setup.sh --test; open with `rerun FILE.rrd`)",
            _view_args, _view),
]


if __name__ == "__main__":
    raise SystemExit(main())
