"""Size limits on what a bag makes pe_drake hold in memory: ``rosbags`` decompresses each chunk
whole, ignoring the size the chunk declares, so a small compressed MCAP can inflate to GB.

:func:`check_mcap_chunks` walks the records of an ``.mcap`` file (headers only) and inflates each
compressed chunk in 16 MB pieces that are counted and dropped, refusing a chunk over
:data:`pe_drake.limits.BAG_CHUNK` or larger than it declares. :func:`check_message_size` bounds one
serialized message (:data:`pe_drake.limits.BAG_MESSAGE`).
"""

from __future__ import annotations

import contextlib
import struct
from pathlib import Path

from pe_drake import limits
from pe_drake.exceptions import DataError

MCAP_MAGIC = b"\x89MCAP0\r\n"
_CHUNK, _FOOTER = 0x06, 0x02
_PIECE = 16 * 2**20


def check_message_size(raw: bytes, index: int, topic: str, file: str) -> None:
    """Refuses a serialized message over :data:`pe_drake.limits.BAG_MESSAGE`, naming it."""
    if len(raw) > limits.in_bytes(limits.BAG_MESSAGE):
        raise DataError(f"message {index} on '{topic}' has {len(raw) / 2**20:.1f} MB; a JointState of a robot "
                        f"is a few kB: over {limits.describe(limits.BAG_MESSAGE)}", file=file)


def check_compressed_bag(path: str | Path) -> None:
    """Refuses a rosbag2 folder compressed per message or per file (``ros2 bag record
    --compression-mode``) whose zstd data inflates past :data:`pe_drake.limits.BAG_MESSAGE` per
    message or :data:`pe_drake.limits.BAG_FILE` per storage file (rosbags inflates them
    without a bound), naming the file."""
    import yaml  # PyYAML, a dependency of pydrake

    path = Path(path)
    try:
        info = yaml.safe_load((path / "metadata.yaml").read_text()).get("rosbag2_bagfile_information") or {}
    except (OSError, yaml.YAMLError, AttributeError):
        return  # rosbags names what is wrong with it
    mode = str(info.get("compression_mode") or "").lower()
    files = [path / Path(str(name)).name for name in info.get("relative_file_paths") or []]
    limit = limits.in_bytes(limits.BAG_FILE)
    if mode == "file":
        for part in files:
            if part.is_file() and _inflated_file_size(part, limit + 1) > limit:
                raise DataError(f"inflates past {limits.describe(limits.BAG_FILE)} (a decompression bomb?)",
                                file=str(part))
    elif mode == "message":
        for part in files:
            if part.suffix == ".db3" and part.is_file():
                _check_db3_messages(part)


def _inflated_file_size(path: Path, cap: int) -> int:
    """Bytes a zstd file inflates to, read and inflated in 16 MB pieces, stopping past ``cap``."""
    from backports import zstd  # lazy, as rosbags imports it (Python < 3.14)

    total, decompressor, pending = 0, zstd.ZstdDecompressor(), b""
    with path.open("rb") as f:
        while total < cap:
            if decompressor.eof:  # frames one after another
                pending, decompressor = decompressor.unused_data + pending, zstd.ZstdDecompressor()
            if decompressor.needs_input:
                block, pending = pending or f.read(_PIECE), b""
                if not block:
                    break
                total += len(decompressor.decompress(block, max_length=_PIECE))
            else:
                total += len(decompressor.decompress(b"", max_length=_PIECE))
    return total


def _check_db3_messages(part: Path) -> None:
    import sqlite3

    limit = limits.in_bytes(limits.BAG_MESSAGE)
    with contextlib.closing(sqlite3.connect(f"file:{part}?mode=ro", uri=True)) as db:
        for index, (data,) in enumerate(db.execute("SELECT data FROM messages ORDER BY id")):
            if _inflated_size(bytes(data), "zstd", limit + 1) > limit:
                raise DataError(f"message {index} inflates past {limits.describe(limits.BAG_MESSAGE)} "
                                "(a decompression bomb?)", file=str(part))


def check_mcap_chunks(path: str | Path) -> None:
    """Refuses an MCAP file (or a folder's) with a chunk that inflates over
    :data:`pe_drake.limits.BAG_CHUNK` or over the size it declares, naming the chunk's offset.
    Other files pass unread."""
    path = Path(path)
    if path.is_dir():
        for part in sorted(path.glob("*.mcap")):
            check_mcap_chunks(part)
        return
    if path.suffix.lower() != ".mcap":
        return
    limit = limits.in_bytes(limits.BAG_CHUNK)
    try:
        _walk_records(path, limit)
    except DataError:
        raise
    except (OSError, struct.error, ValueError, RuntimeError):  # DataError is a ValueError too: raised above
        return  # a damaged file: rosbags names what is wrong with it


def _walk_records(path: Path, limit: int) -> None:
    with path.open("rb") as f:
        if f.read(8) != MCAP_MAGIC:
            return  # rosbags names a file that is not MCAP
        while True:
            head = f.read(9)
            if len(head) < 9:
                return
            opcode, length = struct.unpack("<BQ", head)
            if opcode == _FOOTER:
                return
            start = f.tell()
            if opcode == _CHUNK:
                _check_chunk(f, start, length, limit, str(path))
            f.seek(start + length)


def _check_chunk(f, start: int, length: int, limit: int, file: str) -> None:
    fixed = f.read(28)  # start and end time, uncompressed size, CRC
    if len(fixed) < 28:
        return
    declared = struct.unpack_from("<Q", fixed, 16)[0]
    (name_length,) = struct.unpack("<I", f.read(4))
    compression = f.read(min(name_length, 64)).decode("ascii", "replace")
    f.seek(start + 32 + name_length)
    (size,) = struct.unpack("<Q", f.read(8))
    where = f"the chunk at byte {start - 9} ({compression or 'uncompressed'})"
    if declared > limit:
        raise DataError(f"{where} holds {declared / 2**20:.0f} MB: over {limits.describe(limits.BAG_CHUNK)}", file=file)
    if compression not in ("zstd", "lz4"):
        return
    try:
        inflated = _inflated_size(f.read(min(size, length)), compression, declared + 1)
    except Exception:  # noqa: BLE001 (zstd/lz4 errors of damaged data: rosbags reports them)
        return
    if inflated > declared:
        raise DataError(f"{where} inflates to more than the {declared} bytes it declares (a decompression bomb): "
                        "refused before reading it", file=file)


def _inflated_size(data: bytes, compression: str, cap: int) -> int:
    """Bytes ``data`` inflates to, counted in pieces and dropped, stopping past ``cap``."""
    total = 0
    while data and total < cap:
        if compression == "zstd":
            from backports import zstd  # lazy, as rosbags imports it (Python < 3.14)
            decompressor = zstd.ZstdDecompressor()
        else:
            import lz4.frame  # lazy, a rosbags dependency
            decompressor = lz4.frame.LZ4FrameDecompressor()
        piece = decompressor.decompress(data, max_length=_PIECE)
        total += len(piece)
        while not decompressor.eof and not decompressor.needs_input and total < cap:
            total += len(decompressor.decompress(b"", max_length=_PIECE))
        if not decompressor.eof:
            break  # a truncated frame: rosbags reports it
        data = decompressor.unused_data
    return total
