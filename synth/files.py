"""Files of the dataset contract: JSON, PNG, JPEG (an RGB image with ``sensor.jpeg_quality``) and single-channel
EXR z-depth, each written whole or not at all (`corelib.atomic`) and read with an error that names the file
(`DatasetError`).

Example::

    write_depth_exr("d.depth.exr", depth)          # (H, W) float32 metres, channel "Z"
    depth = read_depth_exr("d.depth.exr")
"""
from __future__ import annotations

import contextlib
import io
import os
import re
import stat
import sys
import tempfile
import threading
from pathlib import Path

import cv2
import numpy as np

from corelib.atomic import atomic_write_bytes, atomic_write_json
from corelib.readfile import read_bounded
from synth.image_headers import check_exr_single_part, check_jpeg_header, check_png_header, jpeg_size
from synth.rig import MAX_CAMERA_PX

DEPTH_CHANNEL = "Z"


class DatasetError(RuntimeError):
    """The dataset on disk is missing, incomplete, of another version or corrupt; the message names the file."""


_PLAIN_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")


def is_plain_name(name) -> bool:
    """A string of letters, digits, ``. _ -`` (at most 128, starting with a letter or digit): no path
    separator, never ``.`` or ``..``; safe as one folder or file name."""
    return isinstance(name, str) and bool(_PLAIN_NAME.match(name)) and name not in (".", "..")


def short_list(items: list[str], n: int = 6) -> str:
    """The first `n` of `items`, comma-separated, and how many more."""
    return ", ".join(items[:n]) + (f" (+{len(items) - n} more)" if len(items) > n else "")


class OutputFolderError(RuntimeError):
    """The output folder holds something else (another dataset or unrelated files)."""


def write_json(path: str | Path, obj) -> None:
    """JSON written whole or not at all (`corelib.atomic`)."""
    atomic_write_json(path, obj)


def within(root: str | Path, path: str | Path, who: str = "", kind: str = "dataroot",
           verb: str = "resolves to") -> Path:
    """`path` when it resolves inside `root` (a dataset or a nuScenes dataroot); a file that a table or
    manifest names outside it (``../``, an absolute name) or that is a symbolic link out of it is never
    read (DatasetError naming it and `who` names it, e.g. ``sample_data <token>``)."""
    path = Path(path)
    real, real_root = path.resolve(), Path(root).resolve()
    if not real.is_relative_to(real_root):
        raise DatasetError(f"{path}: {verb} {real}, outside the {kind} {real_root}{f' ({who})' if who else ''}; a "
                           f"{kind.split()[0]}'s files must lie inside it")
    return path


def _not_regular(st: os.stat_result) -> str:
    m = st.st_mode
    return ("a folder" if stat.S_ISDIR(m) else "a FIFO (named pipe)" if stat.S_ISFIFO(m) else "a character device"
            if stat.S_ISCHR(m) else "a block device" if stat.S_ISBLK(m) else "a socket" if stat.S_ISSOCK(m)
            else "not a regular file")


#: the largest file any reader takes (its size is checked on the open descriptor before a byte is read): a
#: 4096 x 4096 float32 EXR is 64 MiB, the largest nuScenes table (v1.0-trainval sample_data.json) about 1 GiB
MAX_READ_BYTES = 2 * 2**30


def regular_file(path: str | Path, root: str | Path | None = None, who: str = "") -> Path:
    """`path` when it is a regular file (a link is followed; with `root`, it must resolve inside it,
    `within`); a FIFO, a device, a socket, a folder or a file larger than `MAX_READ_BYTES` is refused without
    being opened (os.stat), naming the file: the rule of every reader of a dataset's or dataroot's files."""
    path = Path(path)
    if root is not None:
        within(root, path, who)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise DatasetError(f"{path}: file is missing") from None
    except OSError as exc:
        raise DatasetError(f"{path}: missing or not readable ({exc.strerror or exc})") from None
    if not stat.S_ISREG(st.st_mode):
        raise DatasetError(f"{path}: is {_not_regular(st)}, not a regular file; a dataset's files are regular files")
    _check_size(path, st)
    return path


def _check_size(path: Path, st: os.stat_result) -> None:
    if st.st_size > MAX_READ_BYTES:
        raise DatasetError(f"{path}: {st.st_size} bytes, more than any dataset file may hold ({MAX_READ_BYTES} "
                           "bytes); refused before reading")


def read_regular(path: str | Path, root: str | Path | None = None, who: str = "") -> bytes:
    """The bytes of the regular file `path` (`regular_file`'s rule), at most `MAX_READ_BYTES`. Opened with
    O_NONBLOCK and checked again on the open descriptor, so a FIFO put in its place after the check never
    blocks the read, and a file larger than the bound is refused before it is read."""
    path = regular_file(path, root, who)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except OSError as exc:
        raise DatasetError(f"{path}: missing or not readable ({exc.strerror or exc})") from None
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise DatasetError(f"{path}: is {_not_regular(st)}, not a regular file; a dataset's files are regular "
                               "files")
        _check_size(path, st)  # again on the descriptor: the file may have been replaced since
        try:  # in chunks as the file has them, never one buffer of the bound (2 GiB asked of every read)
            data = read_bounded(f, MAX_READ_BYTES)
        except OSError as exc:
            raise DatasetError(f"{path}: not readable ({exc.strerror or exc})") from None
        if len(data) > MAX_READ_BYTES:
            raise DatasetError(f"{path}: grew past {MAX_READ_BYTES} bytes while read; refused")
        return data


def read_json(path: str | Path, root: str | Path | None = None, who: str = ""):
    """The JSON value of the regular file `path` (`read_regular`); bytes that are not UTF-8 JSON are
    refused naming the file."""
    from corelib.readfile import decode_json

    path = Path(path)
    return decode_json(read_regular(path, root, who), path, DatasetError)


PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def encode_png(img: np.ndarray, compression: int = 3) -> bytes:
    """uint8 RGB (H, W, 3) or gray (H, W), or uint16 gray (H, W) (an instance map) -> PNG file bytes."""
    if img.dtype != np.uint8 and not (img.dtype == np.uint16 and img.ndim == 2):
        raise ValueError(f"write_png: expected uint8 (or uint16 gray), got {img.dtype}")
    arr = img[:, :, ::-1] if img.ndim == 3 else img
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(arr), [cv2.IMWRITE_PNG_COMPRESSION, int(compression)])
    if not ok:
        raise ValueError("write_png: could not encode the image")
    return buf.tobytes()


def encode_jpeg(rgb: np.ndarray, quality: int) -> bytes:
    """uint8 RGB (H, W, 3) -> baseline JPEG file bytes at `quality` (1..100; OpenCV's libjpeg, 4:2:0 chroma
    subsampling, as nuScenes' camera images), the same bytes for the same pixels."""
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"encode_jpeg: expected (H, W, 3) uint8, got {rgb.shape} {rgb.dtype}")
    if not 1 <= int(quality) <= 100:
        raise ValueError(f"encode_jpeg: quality must be in 1..100, got {quality}")
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("encode_jpeg: could not encode the image")
    return buf.tobytes()


#: an RGB image's file suffix by its format (the manifest's ``rgb.format``; absent: png), the one table of it
RGB_SUFFIXES = {"png": ".png", "jpeg": ".jpg"}


def write_png(path: str | Path, img: np.ndarray, compression: int = 3, fsync: bool = True) -> None:
    """Write uint8 RGB (H, W, 3) or gray (H, W) as PNG, whole or not at all (`fsync=False` inside a
    folder that is itself sealed by a rename, see `render_sequence`)."""
    atomic_write_bytes(path, encode_png(img, compression), fsync=fsync)


def read_png(path: str | Path, gray: bool = False, depth16: bool = False) -> np.ndarray:
    """(H, W, 3) uint8 RGB or (H, W) gray of an 8-bit PNG file (``depth16``: (H, W) uint16, a 16-bit gray PNG
    such as an instance map); a file of any other format (a JPEG under a .png name) is refused by its first
    bytes, and a 16-bit PNG where 8 bits are the contract (a semantic map) by its header, naming the file."""
    path = Path(path)
    data = read_regular(path)
    if not data.startswith(PNG_SIGNATURE):
        kind = "a JPEG file" if data.startswith(b"\xff\xd8\xff") else "another format"
        raise DatasetError(f"{path}: not a readable PNG ({kind}: its first bytes are not the PNG signature)")
    check_png_header(path, data, DatasetError)
    if not depth16 and data[24] == 16:  # IHDR's bit depth: OpenCV would narrow it to 8 bits without a word
        raise DatasetError(f"{path}: is a 16-bit PNG; the contract is an 8-bit {'gray' if gray else 'RGB'} PNG")
    flags = cv2.IMREAD_UNCHANGED if depth16 else cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_COLOR
    img = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if img is None:
        raise DatasetError(f"{path}: not a readable PNG (truncated or corrupt)")
    if depth16:
        if img.dtype != np.uint16 or img.ndim != 2:
            raise DatasetError(f"{path}: is {img.dtype} with shape {img.shape}; the contract is a 16-bit gray PNG")
        return img
    return img if gray else np.ascontiguousarray(img[:, :, ::-1])


JPEG_SIGNATURE = b"\xff\xd8\xff"
#: what an image file's name promises, by its suffix: the signature its first bytes must carry
IMAGE_SIGNATURES = {".png": (PNG_SIGNATURE, "PNG"), ".jpg": (JPEG_SIGNATURE, "JPEG"), ".jpeg": (JPEG_SIGNATURE, "JPEG")}


def read_image(path: str | Path) -> np.ndarray:
    """(H, W, 3) uint8 RGB of a .png or .jpg file (a nuScenes dataroot's camera images) whose first bytes
    are those its name promises: a file of another format under that name is refused, naming the file."""
    path = Path(path)
    sig, kind = IMAGE_SIGNATURES.get(path.suffix.lower(), (None, path.suffix))
    if sig is None:
        raise DatasetError(f"{path}: not a .png or .jpg image")
    data = read_regular(path)
    if not data.startswith(sig):
        raise DatasetError(f"{path}: not a readable {kind} (its first bytes are not the {kind} signature)")
    (check_png_header if kind == "PNG" else check_jpeg_header)(path, data, DatasetError)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    if img is None:
        raise DatasetError(f"{path}: not a readable {kind} (truncated or corrupt)")
    return np.ascontiguousarray(img[:, :, ::-1])


def _encode_exr(channels: dict[str, np.ndarray]) -> bytes:
    """A ZIP-compressed scanline OpenEXR of float32 (H, W) `channels`, encoded in memory: OpenEXR takes a file
    name only as UTF-8 text, so Python writes the bytes (any folder name, a Latin-1 one under ``LC_ALL=C`` too)."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    buf = io.BytesIO()
    with OpenEXR.File(header, {k: np.ascontiguousarray(v) for k, v in channels.items()}) as f:
        f.write(buf)
    return buf.getvalue()


def write_depth_exr(path: str | Path, depth: np.ndarray, fsync: bool = True) -> None:
    """Write (H, W) float32 z-depth in metres as a single-channel ("Z") ZIP-compressed OpenEXR, whole or
    not at all (`_encode_exr`)."""
    if depth.ndim != 2 or depth.dtype != np.float32:
        raise ValueError(f"write_depth_exr: expected (H, W) float32, got {depth.shape} {depth.dtype}")
    atomic_write_bytes(path, _encode_exr({DEPTH_CHANNEL: depth}), fsync=fsync)


def _exr_header(f) -> tuple[int, int, list[str]]:
    """(width, height, channel names) of an OpenEXR file object's header: its data window and channel list
    (nothing else is read; OpenEXR's own messages silenced, `_quiet_fd2`)."""
    import OpenEXR

    with _quiet_fd2(), OpenEXR.File(f, header_only=True) as exr:
        header = exr.header()  # emptied when the file closes
        lo, hi = header["dataWindow"]
        names = [str(c.name) for c in header.get("channels", [])]
        return int(hi[0]) - int(lo[0]) + 1, int(hi[1]) - int(lo[1]) + 1, names


def _exr_size(f) -> tuple[int, int]:
    """(width, height) of the data window of an OpenEXR file object's header (nothing else is read)."""
    return _exr_header(f)[:2]


_FD2_LOCK = threading.Lock()


@contextlib.contextmanager
def _quiet_fd2():
    """File descriptor 2 sent to a temporary file while OpenEXR runs: its C++ library writes its own lines about a
    truncated or corrupt file there ("Warning: Exception raised reading pixel data ...", "EXR_ERR_BAD_CHUNK_LEADER
    ..."), before the reader's one-line DatasetError says what is wrong. Whatever was written is written back to
    stderr when the block succeeds and dropped when it fails (it is OpenEXR's account of that failure). The
    descriptor is the process's: one block at a time (a lock)."""
    with _FD2_LOCK:
        saved = None
        try:
            sys.stderr.flush()
            saved = os.dup(2)
        except (OSError, ValueError, AttributeError):  # no stderr to keep quiet
            pass
        if saved is None:
            yield
            return
        ok = False
        try:
            with tempfile.TemporaryFile() as tmp:
                os.dup2(tmp.fileno(), 2)
                try:
                    yield
                    ok = True
                finally:
                    os.dup2(saved, 2)
                    if ok and tmp.tell():
                        tmp.seek(0)
                        os.write(2, tmp.read())
        finally:
            os.close(saved)


def _read_exr(path: str | Path, names: tuple[str, ...], what: str,
              size: tuple[int, int] | None = None) -> list[np.ndarray]:
    """The float32 (H, W) channels `names` of an OpenEXR file, all of one shape. The bytes are read by Python
    (`read_regular`: a regular file, bounded; any file name) and decoded by OpenEXR only once its header is
    checked: a size within bounds (and equal to `size`, (width, height), the camera's, when given) and exactly
    the channels `names` (a small file may claim 66 channels of 4096 x 4096: gigabytes once decoded).
    DatasetError naming the file otherwise (`what`: "depth map", "flow map"); OpenEXR's own messages about a
    corrupt file are silenced (`_quiet_fd2`)."""
    import OpenEXR

    raw = read_regular(path)
    check_exr_single_part(path, raw, DatasetError)
    data = io.BytesIO(raw)
    try:
        w, h, chans = _exr_header(data)  # what it claims, before its pixels are decoded
        if not (0 < w <= MAX_CAMERA_PX and 0 < h <= MAX_CAMERA_PX):
            raise DatasetError(f"{path}: its header claims {w}x{h} pixels, above the {MAX_CAMERA_PX} px a camera's "
                               "side may have; refused before decoding")
        if size is not None and (w, h) != tuple(size):
            raise DatasetError(f"{path}: its header claims {w}x{h} pixels, the camera's images are "
                               f"{size[0]}x{size[1]}; refused before decoding")
        if sorted(chans) != sorted(names):
            shown = ", ".join(repr(c[:40]) for c in chans[:8])
            shown += f" and {len(chans) - 8} more" if len(chans) > 8 else ""
            raise DatasetError(f"{path}: has channel(s) {shown or 'none'}; a {what} has exactly "
                               f"{', '.join(repr(c) for c in names)}; refused before decoding")
        data.seek(0)
        with _quiet_fd2(), OpenEXR.File(data) as f:
            ch = f.channels()
            missing = [c for c in names if c not in ch]
            if missing:
                raise DatasetError(f"{path}: no {', '.join(repr(c) for c in missing)} channel (has {sorted(ch)[:8]})")
            px = [ch[c].pixels for c in names]
            if any(p.dtype != np.float32 or p.ndim != 2 or p.shape != px[0].shape for p in px):
                raise DatasetError(f"{path}: channel(s) {', '.join(names)} must be float32 (FLOAT) of one shape (H, W); "
                                   f"got {[(str(p.dtype), p.shape) for p in px]}")
            return [np.ascontiguousarray(p) for p in px]
    except DatasetError:
        raise
    except Exception as exc:
        raise DatasetError(f"{path}: not a readable EXR {what}, truncated or corrupt ({exc})") from None


def read_depth_exr(path: str | Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W) float32 z-depth in metres, 0 = no surface (`_read_exr`; `size`: the camera's (width, height), checked
    in the header before decoding)."""
    return _read_exr(path, (DEPTH_CHANNEL,), "depth map", size)[0]



FLOW_CHANNELS = ("U", "V")


def write_flow_exr(path: str | Path, flow: np.ndarray, fsync: bool = True) -> None:
    """Write (H, W, 2) float32 optical flow in pixels as a two-channel ("U", "V") ZIP-compressed OpenEXR,
    whole or not at all (`_encode_exr`)."""
    if flow.ndim != 3 or flow.shape[2] != 2 or flow.dtype != np.float32:
        raise ValueError(f"write_flow_exr: expected (H, W, 2) float32, got {flow.shape} {flow.dtype}")
    atomic_write_bytes(path, _encode_exr({c: flow[..., k] for k, c in enumerate(FLOW_CHANNELS)}), fsync=fsync)


def read_flow_exr(path: str | Path, size: tuple[int, int] | None = None) -> np.ndarray:
    """(H, W, 2) float32 optical flow in pixels (du, dv) of a `write_flow_exr` file (`_read_exr`; `size`: the
    camera's (width, height), checked in the header before decoding)."""
    return np.stack(_read_exr(path, FLOW_CHANNELS, "flow map", size), -1)


def stored_size(path: str | Path) -> tuple[int, int] | None:
    """(width, height) of a PNG (its IHDR), a JPEG (its frame header) or an OpenEXR depth map (its data window)
    from the header alone;
    None when the header cannot be read (`verify` reports such a file by its checksum)."""
    path = Path(path)
    try:
        if path.suffix == ".png":
            with open(regular_file(path), "rb") as f:
                head = f.read(24)
            if not head.startswith(PNG_SIGNATURE) or head[12:16] != b"IHDR":
                return None
            return int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
        if path.suffix == ".jpg":
            with open(regular_file(path), "rb") as f:
                head = f.read(2**16)  # the frame header follows the quantisation tables (a few hundred bytes)
            return jpeg_size(head) if head.startswith(JPEG_SIGNATURE) else None
        if path.suffix == ".exr":
            with open(regular_file(path), "rb") as f:
                return _exr_size(f)
    except Exception:  # noqa: BLE001 - an unreadable header: no size, the checksum says what is wrong
        return None
    return None


def frame_stem(frame: int) -> str:
    return f"{frame:06d}"
