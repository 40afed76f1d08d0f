"""Map tiles: tile sources registered by admins, served from MBTiles/PMTiles files or an
upstream XYZ server, and the MapLibre style the browser loads."""
