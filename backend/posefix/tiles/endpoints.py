"""HTTP routes of tile sources, tiles and the map style (mounted under ``/api/v1``)."""

from __future__ import annotations

import hashlib
import json
from typing import Annotated

from fastapi import APIRouter, Header, Request, Response, status

from posefix.deps import AdminUser, AnyUser, SessionDep, SettingsDep
from posefix.errors import ErrorBody, NotFound, responses
from posefix.tiles import service
from posefix.tiles.schemas import TileSourceCreate, TileSourceList, TileSourcePublic
from posefix.tiles.style import build_style

router = APIRouter(tags=["tiles"])

_TILE_MEDIA = {
    "image/png": {}, "image/jpeg": {}, "image/webp": {}, "image/avif": {}, "application/x-protobuf": {},
}


def _base_url(request: Request) -> str:
    return str(request.base_url)


@router.get("/tile-sources", response_model=TileSourceList, responses=responses(401, 403))
def list_tile_sources(request: Request, session: SessionDep, _user: AnyUser) -> TileSourceList:
    """Every registered tile source, in registration order."""
    items = [service.to_public(source, _base_url(request)) for source in service.list_sources(session)]
    return TileSourceList(items=items, total=len(items))


@router.post(
    "/tile-sources", response_model=TileSourcePublic, status_code=status.HTTP_201_CREATED,
    responses=responses(401, 403, 409, 415, 422),
)
def create_tile_source(
    request: Request, body: TileSourceCreate, session: SessionDep, settings: SettingsDep, admin: AdminUser,
) -> TileSourcePublic:
    """Register a tile file in the data directory or an upstream XYZ server (admins)."""
    source = service.create_source(session, settings, body, admin.user_id)
    return service.to_public(source, _base_url(request))


@router.get("/tile-sources/{ref}", response_model=TileSourcePublic, responses=responses(401, 403, 404))
def get_tile_source(request: Request, ref: str, session: SessionDep, _user: AnyUser) -> TileSourcePublic:
    """One tile source by id or name."""
    return service.to_public(service.get_source(session, ref), _base_url(request))


@router.delete(
    "/tile-sources/{ref}", status_code=status.HTTP_204_NO_CONTENT, responses=responses(401, 403, 404),
)
def delete_tile_source(ref: str, session: SessionDep, settings: SettingsDep, _admin: AdminUser) -> Response:
    """Forget a tile source (admins); its file is kept, its upstream cache removed."""
    service.delete_source(session, settings, ref)
    return Response(status_code=status.HTTP_204_NO_CONTENT)


@router.get(
    "/tiles/{source}/{z:int}/{x:int}/{y:int}.{ext}",
    response_class=Response,
    responses={
        200: {"content": _TILE_MEDIA, "description": "The tile, as stored (see Content-Encoding)"},
        204: {"description": "No tile here (vector sources): draw nothing"},
        304: {"description": "Not modified (If-None-Match matched the ETag)"},
        **responses(400, 401, 403, 404),
        502: {"description": "The upstream tile server failed", "model": ErrorBody},
        503: {"description": "The registered tile file is missing or broken", "model": ErrorBody},
    },
)
def get_tile(
    source: str, z: int, x: int, y: int, ext: str, session: SessionDep, settings: SettingsDep, _user: AnyUser,
    if_none_match: Annotated[str | None, Header()] = None,
) -> Response:
    """One XYZ tile of a registered source, with an ETag; 304 when the client's copy is current."""
    tile_source = service.cached_source(session, source)
    tile = service.read_tile(settings, tile_source, z, x, y, ext)
    if tile is None:
        if tile_source.format == "pbf":
            return Response(status_code=status.HTTP_204_NO_CONTENT)
        raise NotFound(f"tile source {source!r} has no tile z={z} x={x} y={y}", code="tile_not_found")
    headers = {
        "ETag": tile.etag,
        # Tiles need a login, so shared caches must not keep them.
        "Cache-Control": f"private, max-age={tile.max_age_s}",
        "Vary": "Accept-Encoding",
    }
    if service.etag_matches(if_none_match, tile.etag):
        return Response(status_code=status.HTTP_304_NOT_MODIFIED, headers=headers)
    if tile.encoding:
        headers["Content-Encoding"] = tile.encoding
    return Response(content=tile.data, media_type=tile.media_type, headers=headers)


@router.get("/map/style.json", responses=responses(401, 403))
def get_style(
    request: Request, session: SessionDep, _user: AnyUser,
    if_none_match: Annotated[str | None, Header()] = None,
) -> Response:
    """The MapLibre style of all registered sources (see ``posefix.tiles.style``)."""
    style = build_style(service.list_sources(session), _base_url(request))
    body = json.dumps(style, separators=(",", ":")).encode()
    etag = '"' + hashlib.blake2b(body, digest_size=16).hexdigest() + '"'
    headers = {"ETag": etag, "Cache-Control": "private, no-cache"}
    if service.etag_matches(if_none_match, etag):
        return Response(status_code=status.HTTP_304_NOT_MODIFIED, headers=headers)
    return Response(content=body, media_type="application/json", headers=headers)
