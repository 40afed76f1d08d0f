"""Request and response bodies of the map-matching API (floor metres: x east, y north)."""

from __future__ import annotations

import datetime as dt
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator


class FloorPlanPublic(BaseModel):
    model_config = ConfigDict(from_attributes=True)
    id: int
    name: str
    source: str = Field(description="competition (floor_info.json + geojson_map.json + floor_image.png) or geojson")
    status: str = Field(description="queued (model job pending), ready, failed")
    cell_m: float = Field(description="graph cell size, metres")
    width_m: float
    height_m: float
    georef: list[float] | None = Field(description="[lon0, lat0, dlon_per_m, dlat_per_m] or null")
    has_image: bool
    n_vertices: int | None
    model_bytes: int | None = Field(description="size of the device model download, bytes")
    build_s: float | None = Field(description="model build time, seconds")
    error: str | None
    job_id: int | None
    created_at: dt.datetime


class FloorPlanList(BaseModel):
    items: list[FloorPlanPublic]
    total: int


class FloorPlanCreated(FloorPlanPublic):
    pass


class SessionCreate(BaseModel):
    start_xy_m: list[float] | None = Field(
        default=None, min_length=2, max_length=2,
        description="known start [x, y] in floor metres; omit for an unknown start (uniform over the floor)",
    )


class Position(BaseModel):
    t_ms: int = Field(description="time of the step (unix ms, as given)")
    x_m: float
    y_m: float
    lon: float | None = None
    lat: float | None = None
    sigma_major_m: float = Field(description="1σ semi-major axis of the position's error ellipse")
    sigma_minor_m: float
    angle_deg: float = Field(description="major axis, counter-clockwise from +x (east)")


class SessionCreated(BaseModel):
    session_id: str
    floorplan_id: int
    expires_in_s: float
    position: Position


class StepIn(BaseModel):
    """One detected step: a floor-frame vector (``dx_m``, ``dy_m``), or a sensor heading
    (rad, counter-clockwise from east, before the model's heading bias) and a length."""

    t_ms: int = Field(ge=0, le=10**14)
    dx_m: float | None = Field(default=None, ge=-5, le=5)
    dy_m: float | None = Field(default=None, ge=-5, le=5)
    heading_rad: float | None = Field(default=None, ge=-10, le=10)
    length_m: float | None = Field(default=None, ge=0, le=5)

    @model_validator(mode="after")
    def _one_form(self) -> StepIn:
        vec = self.dx_m is not None and self.dy_m is not None
        hl = self.heading_rad is not None and self.length_m is not None
        if vec == hl:
            raise ValueError("give either dx_m and dy_m, or heading_rad and length_m")
        return self


class SensorBatch(BaseModel):
    """Raw samples (the competition's path-file columns): ``acc`` rows [t_ms, ax, ay, az]
    (m/s²), ``rotvec`` rows [t_ms, x, y, z] (Android rotation vector). Steps are detected on
    the session's buffer; a step is reported once 0.6 s of samples follow it."""

    acc: list[list[float]] = Field(default_factory=list, max_length=20000)
    rotvec: list[list[float]] = Field(default_factory=list, max_length=20000)


class StepsIn(BaseModel):
    steps: list[StepIn] = Field(default_factory=list, max_length=5000)
    sensors: SensorBatch | None = None

    @model_validator(mode="after")
    def _something(self) -> StepsIn:
        if not self.steps and self.sensors is None:
            raise ValueError("give steps or sensors")
        if self.steps and self.sensors is not None:
            raise ValueError("give steps or sensors, not both")
        return self


class StepsOut(BaseModel):
    session_id: str
    n_steps: int = Field(description="steps tracked in this session so far")
    positions: list[Position] = Field(description="one per step of this request, in order")
    expires_in_s: float


class SuggestionRequest(BaseModel):
    revision: int | None = Field(default=None, ge=0, le=10**9, description="default: the latest ready revision")
    cell_m: float = Field(default=2.0, ge=0.5, le=10.0, description="drivable-area grid cell size, metres (matcher grid)")
    matcher: Literal["roads", "grid"] = Field(
        default="roads", description="roads: candidate projections onto the road network (the default; the grid takes "
                                     "over when most keyframes have no road within 50 m); grid: the drivable-area grid")


class KeyframeSuggestion(BaseModel):
    index: int
    lon: float
    lat: float
    moved_m: float = Field(description="distance from the keyframe's position at this revision")
    off_road: bool = Field(description="the keyframe lies off the drivable area")
    sigma_m: float = Field(description="1σ of the match at this keyframe, metres")
    adjustable: bool = Field(description="the run's rules let an operator move this keyframe")


class SuggestionsJob(BaseModel):
    job_id: int = Field(description="follow with GET /jobs/{id}; its result is a SuggestionsOut")
    status: str
    run_id: int
    revision: int


class SuggestionsOut(BaseModel):
    run_id: int
    revision: int
    osm: str = Field(description="the OpenStreetMap extract matched against (file name)")
    matcher: str = Field(description="the matcher that answered: roads or grid")
    n_vertices: int = Field(description="road segments (roads) or grid vertices (grid) around the run")
    time_ms: float
    off_road: int = Field(description="keyframes off the drivable area")
    items: list[KeyframeSuggestion]


WalkStart = Literal["first_waypoint", "unknown"]


class WalkTrack(BaseModel):
    """A tracked walk as GeoJSON in floor metres (``crs`` names the frame)."""

    model_config = ConfigDict(extra="allow")
    type: Literal["FeatureCollection"] = "FeatureCollection"
    crs: dict[str, Any]
    features: list[dict[str, Any]]
    steps: list[dict[str, Any]]
    errors: dict[str, Any]
