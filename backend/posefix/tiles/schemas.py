"""Request and response bodies of the tile-source API."""

from __future__ import annotations

import datetime as dt

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from posefix.tiles.models import TileFormat, TileKind

NAME_PATTERN = r"^[a-z][a-z0-9_-]{0,63}$"


class TileSourceCreate(BaseModel):
    """Register a basemap: exactly one of ``path`` (an .mbtiles/.pmtiles file inside the data
    directory, relative to it) or ``url`` (an XYZ template with ``{z}``, ``{x}`` and ``{y}``
    or ``{-y}``). Zooms and format default to what the file declares."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field(pattern=NAME_PATTERN, description="URL-safe id: /tiles/{name}/{z}/{x}/{y}.{format}")
    title: str | None = Field(default=None, max_length=200)
    kind: TileKind
    attribution: str = Field(default="", max_length=1000)
    min_zoom: int | None = Field(default=None, ge=0, le=24)
    max_zoom: int | None = Field(default=None, ge=0, le=24)
    format: TileFormat | None = None
    path: str | None = Field(default=None, min_length=1, max_length=1000)
    url: str | None = Field(default=None, min_length=1, max_length=2000)
    tile_size: int = Field(default=256, description="256 or 512 pixels (raster tiles)")

    @field_validator("title", "attribution", "path", "url")
    @classmethod
    def _no_control_characters(cls, value: str | None) -> str | None:
        # PostgreSQL cannot store NUL, and no attribution or path needs a control character.
        if value is not None and any(ord(ch) < 32 or ord(ch) == 127 for ch in value):
            raise ValueError("must not contain control characters")
        return value

    @field_validator("format", mode="before")
    @classmethod
    def _format_alias(cls, value: object) -> object:
        return "jpg" if isinstance(value, str) and value.lower() == "jpeg" else value

    @model_validator(mode="after")
    def _one_origin(self) -> TileSourceCreate:
        if (self.path is None) == (self.url is None):
            raise ValueError("give exactly one of 'path' (a tile file) or 'url' (an upstream XYZ template)")
        if self.min_zoom is not None and self.max_zoom is not None and self.min_zoom > self.max_zoom:
            raise ValueError(f"min_zoom {self.min_zoom} is above max_zoom {self.max_zoom}")
        if self.tile_size not in (256, 512):
            raise ValueError(f"tile_size must be 256 or 512, not {self.tile_size}")
        return self


class TileSourcePublic(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    name: str
    title: str
    kind: TileKind
    attribution: str
    min_zoom: int
    max_zoom: int
    format: TileFormat
    origin: str = Field(description="'file' or 'upstream'")
    path: str | None
    url: str | None
    tile_size: int
    bounds: list[float] | None
    tile_url: str = Field(description="Template of this source's tiles on this server")
    created_at: dt.datetime


class TileSourceList(BaseModel):
    items: list[TileSourcePublic]
    total: int
