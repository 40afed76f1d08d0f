"""Checking uploaded files before anything is stored: names, sizes, archives, images.

Refused: names with directory parts, ``..``, absolute paths or control characters (path
traversal); archives whose members expand more than ``max_zip_ratio`` times, declare more
than the size limit, or hold too many files (zip bombs) — members are read with a hard cap
so a lying header cannot exceed it; images Pillow cannot decode or that decode to more than
``MAX_IMAGE_PIXELS`` (decompression bombs). Every refusal names the file.
"""

from __future__ import annotations

import io
import re
import shutil
import warnings
import zipfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath
from typing import BinaryIO

import exifread
from PIL import Image

from posefix.config import Settings
from posefix.errors import BadRequest, PayloadTooLarge, Unprocessable
from posefix.io import FILE_EXTENSIONS

IMAGE_TYPES = {".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".png": "image/png", ".webp": "image/webp"}
# What the readers know by extension, and a zip of a run folder (KITTI oxts, comma2k19): the
# one list the upload form offers too (GET /api/v1/upload-formats).
RUN_EXTENSIONS = frozenset(FILE_EXTENSIONS) | {".zip"}
MAX_IMAGE_PIXELS = 100_000_000
_BAD_NAME = re.compile(r"[\x00-\x1f\x7f]")
CHUNK = 1 << 20


def safe_name(name: str | None, what: str) -> str:
    """The name itself if it is a plain file name; refuses anything that could escape a folder."""
    if not name:
        raise BadRequest(f"{what}: the file has no name", code="bad_filename")
    if _BAD_NAME.search(name) or "/" in name or "\\" in name or name in (".", "..") or name.startswith(".."):
        raise BadRequest(f"{what}: file name {name!r} is not a plain file name (path traversal refused)", code="unsafe_path",
                         extra={"file": name})
    if len(name) > 200:
        raise BadRequest(f"{what}: file name longer than 200 characters", code="bad_filename", extra={"file": name[:200]})
    return name


def safe_member_name(name: str, archive: str) -> str:
    """A zip member's path must stay inside the archive folder; returns its base name."""
    if _BAD_NAME.search(name) or name.startswith("/") or "\\" in name or re.match(r"^[A-Za-z]:", name):
        raise BadRequest(f"{archive}: member {name!r} has an unsafe path (path traversal refused)", code="unsafe_path",
                         extra={"file": archive, "member": name})
    parts = PurePosixPath(name).parts
    if any(p == ".." for p in parts):
        raise BadRequest(f"{archive}: member {name!r} climbs out of the archive (path traversal refused)", code="unsafe_path",
                         extra={"file": archive, "member": name})
    return parts[-1] if parts else ""


def copy_limited(src: BinaryIO, dst: Path, limit: int, what: str) -> int:
    """Copy at most ``limit`` bytes; refuse (413) beyond that."""
    total = 0
    with open(dst, "wb") as out:
        while True:
            chunk = src.read(CHUNK)
            if not chunk:
                break
            total += len(chunk)
            if total > limit:
                raise PayloadTooLarge(f"{what} is larger than the limit of {limit} bytes", code="file_too_large", extra={"file": what})
            out.write(chunk)
    return total


def open_zip(path: Path, name: str) -> zipfile.ZipFile:
    try:
        return zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as exc:
        raise Unprocessable(f"{name}: not a readable zip archive ({exc})", code="bad_archive", extra={"file": name}) from None


def check_zip(zf: zipfile.ZipFile, name: str, settings: Settings, *, max_total: int, max_files: int) -> list[zipfile.ZipInfo]:
    """The archive's file members after the bomb checks on the declared sizes."""
    members = [m for m in zf.infolist() if not m.is_dir()]
    if len(members) > max_files:
        raise PayloadTooLarge(f"{name}: {len(members)} files, more than the limit of {max_files}", code="too_many_files",
                              extra={"file": name})
    total = 0
    for m in members:
        safe_member_name(m.filename, name)
        if m.flag_bits & 0x1:
            raise Unprocessable(f"{name}: member {m.filename!r} is encrypted", code="bad_archive", extra={"file": name})
        total += m.file_size
        ratio = m.file_size / max(m.compress_size, 1)
        if ratio > settings.max_zip_ratio and m.file_size > CHUNK:
            raise PayloadTooLarge(
                f"{name}: member {m.filename!r} expands {ratio:.0f} times (limit {settings.max_zip_ratio:.0f}); zip bomb refused",
                code="zip_bomb", extra={"file": name, "member": m.filename},
            )
        if total > max_total:
            raise PayloadTooLarge(f"{name}: expands to more than {max_total} bytes; refused", code="zip_bomb", extra={"file": name})
    return members


def extract_member(zf: zipfile.ZipFile, m: zipfile.ZipInfo, dst: Path, archive: str) -> int:
    """Extract with a hard cap at the declared size (a lying header cannot inflate beyond it)."""
    try:
        with zf.open(m) as src:
            n = copy_limited(src, dst, m.file_size, f"{archive}:{m.filename}")
    except (zipfile.BadZipFile, OSError, EOFError) as exc:
        raise Unprocessable(f"{archive}: member {m.filename!r} is corrupt ({exc})", code="bad_archive", extra={"file": archive}) from None
    return n


def extract_run_archive(path: Path, name: str, dest: Path, settings: Settings) -> Path:
    """A zipped run folder (KITTI oxts, comma2k19 segment) extracted safely; returns the folder."""
    zf = open_zip(path, name)
    with zf:
        members = check_zip(zf, name, settings, max_total=settings.max_run_bytes, max_files=100_000)
        for m in members:
            parts = PurePosixPath(m.filename).parts
            target = dest.joinpath(*parts)
            if dest.resolve() not in target.resolve().parents:
                raise BadRequest(f"{name}: member {m.filename!r} escapes the archive", code="unsafe_path", extra={"file": name})
            target.parent.mkdir(parents=True, exist_ok=True)
            extract_member(zf, m, target, name)
    # A single top-level folder is the run folder.
    entries = [p for p in dest.iterdir()]
    return entries[0] if len(entries) == 1 and entries[0].is_dir() else dest


@dataclass
class StagedImage:
    path: Path
    filename: str
    content_type: str
    size_bytes: int
    width: int
    height: int
    exif_lon: float | None
    exif_lat: float | None
    exif_time: str | None


def _ratio(v: object) -> float:
    num = getattr(v, "num", None)
    den = getattr(v, "den", None)
    if num is not None and den:
        return float(num) / float(den)
    return float(v)  # type: ignore[arg-type]


def read_exif_gps(path: Path) -> tuple[float | None, float | None, str | None]:
    """(lon, lat, time) from EXIF, None where absent or unreadable."""
    try:
        with open(path, "rb") as fh:
            tags = exifread.process_file(fh, details=False)
    except Exception:
        return None, None, None
    when = tags.get("EXIF DateTimeOriginal") or tags.get("Image DateTime")
    when_s = str(when)[:32] if when is not None else None

    def coord(key: str, ref_key: str, neg: str) -> float | None:
        tag = tags.get(key)
        if tag is None or len(tag.values) < 3:
            return None
        d, m, s = (_ratio(v) for v in tag.values[:3])
        value = d + m / 60.0 + s / 3600.0
        ref = str(tags.get(ref_key, "")).strip().upper()
        return -value if ref == neg else value

    try:
        lat = coord("GPS GPSLatitude", "GPS GPSLatitudeRef", "S")
        lon = coord("GPS GPSLongitude", "GPS GPSLongitudeRef", "W")
    except (ValueError, ZeroDivisionError, TypeError):
        return None, None, when_s
    if lat is None or lon is None or not (-90 <= lat <= 90 and -180 <= lon <= 180):
        return None, None, when_s
    return lon, lat, when_s


def check_image(path: Path, filename: str) -> StagedImage:
    ext = Path(filename).suffix.lower()
    if ext not in IMAGE_TYPES:
        raise Unprocessable(
            f"{filename}: not an image type posefix accepts ({', '.join(sorted(IMAGE_TYPES))})",
            code="bad_image", extra={"file": filename},
        )
    Image.MAX_IMAGE_PIXELS = MAX_IMAGE_PIXELS
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(path) as im:
                width, height = im.size
                im.verify()
    except (Image.DecompressionBombError, Image.DecompressionBombWarning):
        raise PayloadTooLarge(f"{filename}: image has too many pixels (decompression bomb refused)", code="image_bomb",
                              extra={"file": filename}) from None
    except Exception as exc:
        raise Unprocessable(f"{filename}: not a readable image ({exc})", code="bad_image", extra={"file": filename}) from None
    lon, lat, when = read_exif_gps(path)
    return StagedImage(path, filename, IMAGE_TYPES[ext], path.stat().st_size, width, height, lon, lat, when)


def stage_images(
    uploads: list[tuple[str, BinaryIO]], staging: Path, settings: Settings
) -> list[StagedImage]:
    """Images given one by one and/or as zip archives, checked and copied into ``staging``."""
    out: list[StagedImage] = []
    seen: set[str] = set()
    budget = settings.max_images_bytes
    d = staging / "images"
    d.mkdir()

    def add(path: Path, filename: str) -> None:
        nonlocal budget
        if filename in seen:
            raise BadRequest(f"image {filename!r} given twice", code="duplicate_image", extra={"file": filename})
        seen.add(filename)
        if len(out) >= settings.max_image_count:
            raise PayloadTooLarge(f"more than {settings.max_image_count} images", code="too_many_files")
        out.append(check_image(path, filename))

    for raw_name, fh in uploads:
        name = safe_name(raw_name, "images")
        if Path(name).suffix.lower() == ".zip":
            zpath = d / f"upload-{len(out)}-{len(seen)}.zip"
            budget -= copy_limited(fh, zpath, budget, name)
            zf = open_zip(zpath, name)
            with zf:
                members = check_zip(zf, name, settings, max_total=settings.max_images_bytes, max_files=settings.max_image_count)
                for m in members:
                    base = safe_member_name(m.filename, name)
                    if base.startswith(".") or "__MACOSX" in m.filename:
                        continue
                    if m.file_size > settings.max_image_bytes:
                        raise PayloadTooLarge(f"{name}: {base} is larger than {settings.max_image_bytes} bytes",
                                              code="file_too_large", extra={"file": name, "member": m.filename})
                    target = d / f"{len(out)}{Path(base).suffix.lower()}"
                    extract_member(zf, m, target, name)
                    add(target, base)
            zpath.unlink()
        else:
            target = d / f"{len(out)}{Path(name).suffix.lower()}"
            n = copy_limited(fh, target, min(settings.max_image_bytes, budget), name)
            budget -= n
            add(target, name)
    return out


def stage_run_file(fh: BinaryIO, filename: str, staging: Path, settings: Settings) -> tuple[Path, str]:
    """Copy the run file into staging; unzip a zipped run folder. Returns (path, original name)."""
    name = safe_name(filename, "file")
    ext = Path(name).suffix.lower()
    if ext not in RUN_EXTENSIONS:
        raise Unprocessable(
            f"{name}: unknown run file extension {ext!r} (known: {', '.join(sorted(RUN_EXTENSIONS))})",
            code="invalid_run", extra={"file": name, "line": None, "field": None},
        )
    target = staging / f"run{ext}"
    copy_limited(fh, target, settings.max_run_bytes, name)
    if ext == ".zip":
        folder = staging / "run"
        folder.mkdir()
        return extract_run_archive(target, name, folder, settings), name
    return target, name


def clear(path: Path) -> None:
    shutil.rmtree(path, ignore_errors=True)


def as_binary(data: bytes) -> BinaryIO:
    return io.BytesIO(data)
