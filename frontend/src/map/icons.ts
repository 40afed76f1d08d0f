/** Icons drawn on a canvas at run time (no sprite sheet needed; works offline). */

/** An upward arrow (north = heading 0), white on transparent, as SDF-ready alpha. */
export function arrowIcon(size = 32): ImageData {
  const c = document.createElement("canvas");
  c.width = c.height = size;
  const g = c.getContext("2d")!;
  g.fillStyle = "#fff";
  g.beginPath();
  g.moveTo(size / 2, 1);
  g.lineTo(size - 5, size - 4);
  g.lineTo(size / 2, size - 11);
  g.lineTo(5, size - 4);
  g.closePath();
  g.fill();
  return g.getImageData(0, 0, size, size);
}

/** A small chevron pointing along a line (east = along), for travel-order arrows. */
export function chevronIcon(size = 16): ImageData {
  const c = document.createElement("canvas");
  c.width = c.height = size;
  const g = c.getContext("2d")!;
  g.strokeStyle = "#fff";
  g.lineWidth = 3;
  g.lineCap = "round";
  g.lineJoin = "round";
  g.beginPath();
  g.moveTo(size * 0.3, size * 0.2);
  g.lineTo(size * 0.75, size * 0.5);
  g.lineTo(size * 0.3, size * 0.8);
  g.stroke();
  return g.getImageData(0, 0, size, size);
}
