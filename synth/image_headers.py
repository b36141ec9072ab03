"""Image headers read before an image is decoded: a small PNG or JPEG may claim a size whose decoding takes
gigabytes, so its header's size is checked against `synth.rig.MAX_CAMERA_PX` first (`synth.files` reads the files
and passes its error class). The EXR readers check their header in `synth.files` (OpenEXR's header API), after
its version field here (`check_exr_single_part`: one part, no deep data)."""
from __future__ import annotations

from pathlib import Path

from synth.rig import MAX_CAMERA_PX


def check_png_header(path: Path, data: bytes, error: type[Exception]) -> None:
    """A PNG whose header (IHDR) claims a side above `MAX_CAMERA_PX` is refused before it is decoded: a small
    file may claim 30000 x 30000 pixels (gigabytes once decoded)."""
    if data[12:16] != b"IHDR" or len(data) < 26:  # through the bit depth and colour type
        raise error(f"{path}: not a readable PNG (no IHDR header)")
    w, h = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    if not (0 < w <= MAX_CAMERA_PX and 0 < h <= MAX_CAMERA_PX):
        raise error(f"{path}: its header claims {w}x{h} pixels, above the {MAX_CAMERA_PX} px a camera's side "
                           "may have; refused before decoding")




EXR_MAGIC = b"\x76\x2f\x31\x01"
#: the version field's flags (OpenEXR's file layout): bit 11 deep ("non-image") data, bit 12 several parts
_EXR_DEEP, _EXR_MULTIPART = 0x800, 0x1000


def check_exr_single_part(path: Path, data: bytes, error: type[Exception]) -> None:
    """Refuse an OpenEXR file whose version field says it holds several parts or deep data, before OpenEXR
    sees it: the header check reads part 0 only, and OpenEXR decodes every part (a 4 MB file whose part 1
    claims 64 channels of 4096 x 4096 is gigabytes once decoded). A dataset's maps are single-part scanline
    files (`synth.files._encode_exr`)."""
    if len(data) >= 8 and data[:4] == EXR_MAGIC:
        flags = int.from_bytes(data[4:8], "little")
        if flags & (_EXR_MULTIPART | _EXR_DEEP):
            kind = "several parts (multi-part)" if flags & _EXR_MULTIPART else "deep data"
            raise error(f"{path}: an OpenEXR file of {kind}; a dataset's maps are single-part scanline files; "
                        "refused before decoding")


#: the JPEG markers that start a frame header (SOF0..SOF15 but DHT C4, JPG C8, DAC CC): its size follows
_JPEG_SOF = frozenset(range(0xC0, 0xD0)) - {0xC4, 0xC8, 0xCC}
#: markers with no length field: TEM, RST0..RST7, SOI
_JPEG_BARE = frozenset([0x01, *range(0xD0, 0xD9)])


def jpeg_size(data: bytes) -> tuple[int, int] | None:
    """(width, height) of a JPEG's frame header (SOF), found by walking its marker segments; None when no frame
    header comes before the scan (SOS), the end (EOI) or the end of the bytes."""
    i = 2  # after SOI
    while i + 4 <= len(data):
        if data[i] != 0xFF:
            return None
        marker = data[i + 1]
        if marker == 0xFF:  # a fill byte
            i += 1
            continue
        if marker in _JPEG_BARE:
            i += 2
            continue
        if marker in (0xD9, 0xDA):  # EOI, SOS: no frame header before the image data
            return None
        length = int.from_bytes(data[i + 2:i + 4], "big")
        if marker in _JPEG_SOF:
            if length < 8 or i + 9 > len(data):
                return None
            return int.from_bytes(data[i + 7:i + 9], "big"), int.from_bytes(data[i + 5:i + 7], "big")
        if length < 2:
            return None
        i += 2 + length
    return None


def check_jpeg_header(path: Path, data: bytes, error: type[Exception]) -> None:
    """A JPEG whose frame header (SOF) claims a side above `MAX_CAMERA_PX` (or 0: a height given later, by a DNL
    marker), or that has no frame header, is refused before it is decoded: a 3 KB file may claim 32000 x 32000
    pixels (gigabytes once decoded), the bound of `check_png_header` and of the EXR readers."""
    size = jpeg_size(data)
    if size is None:
        raise error(f"{path}: not a readable JPEG (no frame header before its image data)")
    w, h = size
    if not (w and h):
        raise error(f"{path}: its header claims {w}x{h} pixels (a size given later in the file); refused "
                           "before decoding")
    if not (w <= MAX_CAMERA_PX and h <= MAX_CAMERA_PX):
        raise error(f"{path}: its header claims {w}x{h} pixels, above the {MAX_CAMERA_PX} px a camera's side "
                           "may have; refused before decoding")
