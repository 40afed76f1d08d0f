"""Images: originals and thumbnails (made once, written atomically), access-checked by run."""

from __future__ import annotations

import io

from PIL import Image, ImageOps
from sqlalchemy.orm import Session

from posefix.config import Settings
from posefix.errors import NotFound
from posefix.runs import repository as repo
from posefix.runs.access import get_visible_run
from posefix.runs.models import RunImage
from posefix.filestore import FileStore, file_store
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


def original(settings: Settings, img: RunImage) -> tuple[FileStore, str]:
    return file_store(settings), img.storage_path


def thumbnail(settings: Settings, img: RunImage) -> tuple[FileStore, str]:
    """The thumbnail, made on first request and reused after (a store write appears whole)."""
    fs = file_store(settings)
    rel = f"images/{img.run_id}/{img.id}.thumb.jpg"
    if fs.exists(rel):
        return fs, rel
    with fs.open(img.storage_path) as fh, Image.open(fh) as im:
        im = ImageOps.exif_transpose(im)
        im.thumbnail((THUMBNAIL_PX, THUMBNAIL_PX))
        buf = io.BytesIO()
        im.convert("RGB").save(buf, "JPEG", quality=80)
    fs.put_bytes(buf.getvalue(), rel)
    return fs, rel
