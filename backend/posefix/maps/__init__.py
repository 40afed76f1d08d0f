"""Map matching on the web: floor plans, their models, walk tracking, live tracking
sessions, and map-matching suggestions for pose runs (see docs/maps-api.md)."""
