"""Hardening round six (issue 61): the files the project writes for itself (a sweep's records, results, pages,
checkpoints, its own folders) are read and written by the same rule as the files a user hands in. One test per
finding, each the reproduction that failed before the fix, holding the one-line outcome now."""
from __future__ import annotations

import io
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


# --- finding 1: a multi-part EXR is refused before any part is decoded ---------------------------------------

def _multipart_exr(path: Path, names=("Z",)) -> None:
    import OpenEXR

    h = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    part0 = OpenEXR.Part(dict(h), {c: np.ones((64, 96), np.float32) for c in names}, name="depth")
    part1 = OpenEXR.Part(dict(h), {f"C{i}": np.ones((64, 96), np.float32) for i in range(4)}, name="extra")
    buf = io.BytesIO()
    with OpenEXR.File([part0, part1]) as f:
        f.write(buf)
    path.write_bytes(buf.getvalue())


@pytest.mark.parametrize("reader,names", [("read_depth_exr", ("Z",)), ("read_flow_exr", ("U", "V"))])
def test_multipart_exr_refused_before_decoding(tmp_path, monkeypatch, reader, names):
    import OpenEXR

    import synth.files as files

    path = tmp_path / "000000.depth.exr"
    _multipart_exr(path, names)
    opened = []
    real = OpenEXR.File
    monkeypatch.setattr(OpenEXR, "File", lambda *a, **k: opened.append(k) or real(*a, **k))
    with pytest.raises(files.DatasetError) as e:
        getattr(files, reader)(path)
    assert str(e.value) == (f"{path}: an OpenEXR file of several parts (multi-part); a dataset's maps are "
                            "single-part scanline files; refused before decoding")
    assert opened == []  # OpenEXR never saw it, not even its header


# --- finding 9: no read asks for a buffer of the 2 GiB bound ------------------------------------------------

def test_dataset_read_asks_no_2gib_buffer(tmp_path):
    """Under an address-space limit of 512 MiB above what the process maps, a tiny depth map reads (before:
    MemoryError, `f.read(MAX_READ_BYTES + 1)` asked for 2 GiB whatever the file's size)."""
    code = f"""
import resource
import numpy as np
from synth.files import write_depth_exr, read_depth_exr, read_json
from corelib.readfile import read_text_inside
write_depth_exr({str(tmp_path / 'd.exr')!r}, np.ones((64, 96), np.float32))
open({str(tmp_path / 'r.json')!r}, 'w').write('{{"a": 1}}')
vm = int([l for l in open('/proc/self/status') if l.startswith('VmSize')][0].split()[1]) * 1024
resource.setrlimit(resource.RLIMIT_AS, (vm + 512 * 2**20, resource.getrlimit(resource.RLIMIT_AS)[1]))
print(read_depth_exr({str(tmp_path / 'd.exr')!r}).shape, read_json({str(tmp_path / 'r.json')!r}),
      read_text_inside({str(tmp_path / 'r.json')!r}, {str(tmp_path)!r}, limit=2**31))
"""
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "(64, 96) {'a': 1} {\"a\": 1}"


def test_read_bounded_sees_one_byte_past_the_bound(tmp_path):
    from corelib.readfile import read_bounded

    (tmp_path / "f").write_bytes(b"x" * 100)
    with open(tmp_path / "f", "rb") as f:
        assert len(read_bounded(f, 10)) == 11
    with open(tmp_path / "f", "rb") as f:
        assert read_bounded(f, 1000) == b"x" * 100


# --- finding 6: a tiny sensor.noise is refused by the config check, naming the key ---------------------------

def test_tiny_sensor_noise_refused_naming_key():
    from corelib.configlib import ConfigError
    from synth.config import load_data_config

    with pytest.raises(ConfigError) as e:
        load_data_config(ROOT / "configs/data/tiny.yaml", ["sensor.noise=1e-20"])
    assert str(e.value).splitlines()[-1] == ("  sensor.noise: 0 (no noise) or at least 1e-06 (a million electrons at "
                                             "white; a real sensor holds about 1e4), got 1e-20")
    load_data_config(ROOT / "configs/data/tiny.yaml", ["sensor.noise=1e-6"])  # the smallest allowed renders


# --- finding 12 (last part): a validator's value is echoed once ----------------------------------------------

def test_validator_value_echoed_once():
    from corelib.configlib import ConfigError
    from synth.config import load_data_config

    with pytest.raises(ConfigError) as e:
        load_data_config(ROOT / "configs/data/tiny.yaml", ["weather.fog_density=[0.5,0.1]"])
    assert str(e.value).splitlines()[-1] == ("  weather.fog_density: a fog density range is [lo, hi] with lo <= hi, "
                                             "got [0.5, 0.1]")
