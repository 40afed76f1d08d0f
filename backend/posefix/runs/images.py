"""Images: originals and thumbnails (made once, written atomically), access-checked by run."""

from __future__ import annotations

import io
from pathlib import Path

from PIL import Image, ImageOps
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.errors import NotFound
from posefix.runs import repository as repo
from posefix.runs.access import get_visible_run
from posefix.runs.models import RunImage
from posefix.runs.storage import FileStore
from posefix.users.service import Principal

THUMBNAIL_PX = 320


def visible_image(session: Session, principal: Principal, settings: Settings, image_id: int) -> RunImage:
    img = repo.image(session, image_id)
    if img is None:
        raise NotFound(f"image {image_id} not found", code="image_not_found")
    try:
        get_visible_run(session, principal, settings, img.run_id)
    except NotFound:
        raise NotFound(f"image {image_id} not found", code="image_not_found") from None
    return img


def original_path(settings: Settings, img: RunImage) -> Path:
    return FileStore(settings.files_dir).path(img.storage_path)


def thumbnail_path(settings: Settings, img: RunImage) -> Path:
    """The thumbnail, made on first request and reused after (rename makes it appear whole)."""
    fs = FileStore(settings.files_dir)
    rel = f"images/{img.run_id}/{img.id}.thumb.jpg"
    path = fs.path(rel)
    if path.is_file():
        return path
    with Image.open(fs.path(img.storage_path)) as im:
        im = ImageOps.exif_transpose(im)
        im.thumbnail((THUMBNAIL_PX, THUMBNAIL_PX))
        buf = io.BytesIO()
        im.convert("RGB").save(buf, "JPEG", quality=80)
    fs.put_bytes(buf.getvalue(), rel)
    return path
