"""nuScenes: our datasets written as a nuScenes dataroot, and any dataroot read back as a `DatasetReader`.

Writer and reader of the one format side by side (docs/NUSCENES.md); imports point down this list:

- `layout`: where things lie in a dataroot, the names both sides use, what an export owns;
- `plain`, `geometry`, `tables`: the devkit's parts (its records without it in `plain`; its rotation,
  projection and LiDAR reader in `geometry`) and the tables of a dataroot loaded, named when broken;
- `records`, `lidarseg`, `export`: the writer (the table rows, the labels, the files);
- `dataset`, `scan`, `read`: the reader (the `DatasetReader`, the tables scanned into it, `open_nuscenes`).

Nothing is imported here, so `synth.nuscenes.tables` is cheap to import (`synth.open` asks it first).
"""
