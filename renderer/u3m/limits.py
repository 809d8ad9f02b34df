"""The bounds a U3M read keeps, whatever the input: each is checked before the work it bounds
(a document's size before parsing, an archive's declared sizes before any member is read, an image's
declared size before its pixels are decoded), so a hostile file is refused in bounded time and memory."""

from __future__ import annotations

from dataclasses import dataclass

MiB = 1 << 20

# One image: 8192 x 8192 px. A fabric scan of 20 x 20 cm at 1000 dpi is 7874 px wide; as linear
# float32 RGB such an image holds 0.8 GB.
MAX_IMAGE_PIXELS = 8192 * 8192
# Every image of a material together (an image used by several fields counts once a use as colour,
# scalar or normal data): four images at the limit.
MAX_TOTAL_PIXELS = 4 * MAX_IMAGE_PIXELS
# One file read whole into memory (the document, an image file, an archive's member).
MAX_FILE_BYTES = 256 * MiB
# The JSON document itself: U3M documents are a few kB; a large one is not a material.
MAX_DOCUMENT_BYTES = 16 * MiB
# An archive: its own size on disk and the sum of its members' declared uncompressed sizes.
MAX_ARCHIVE_BYTES = 1024 * MiB
# Uncompressed over compressed size of one member, judged for members that declare more than
# RATIO_FLOOR_BYTES. Deflate reaches about 1032:1 on constant data; images (already compressed) stay
# near 1:1 and JSON near 10:1, so 100:1 on a large member is a bomb, not a fabric.
MAX_COMPRESSION_RATIO = 100.0
RATIO_FLOOR_BYTES = 1 * MiB
# Members of an archive: a material has tens of files.
MAX_MEMBERS = 4096


@dataclass(frozen=True)
class U3MLimits:
    """The bounds of one read (`load_u3m(..., limits=)`); the defaults are the constants above."""

    max_image_pixels: int = MAX_IMAGE_PIXELS
    max_total_pixels: int = MAX_TOTAL_PIXELS
    max_file_bytes: int = MAX_FILE_BYTES
    max_document_bytes: int = MAX_DOCUMENT_BYTES
    max_archive_bytes: int = MAX_ARCHIVE_BYTES
    max_compression_ratio: float = MAX_COMPRESSION_RATIO
    max_members: int = MAX_MEMBERS


DEFAULT_LIMITS = U3MLimits()
