/**
 * NumPy `.npz` reader: a zip (stored or deflated members, zip64 extras as NumPy writes
 * them) of `.npy` arrays (format 1.0-3.0 headers, C order, little-endian numeric dtypes
 * and fixed-width unicode `<U n`). Only what the posefix model and fingerprint files use.
 * Deflate is undone by the platform's `DecompressionStream("deflate-raw")` (browsers and
 * Node 18+), so there is no decompressor to ship.
 */

export class NpzFormatError extends Error {
  constructor(
    readonly file: string,
    readonly field: string,
    message: string,
  ) {
    super(`${file}:0: field ${field}: ${message}`);
    this.name = "NpzFormatError";
  }
}

export type NpyData = Float64Array | Float32Array | Int32Array | Int16Array | Int8Array | Uint8Array | Uint16Array | Uint32Array | string[];

export interface NpyArray {
  dtype: string;
  shape: number[];
  data: NpyData;
}

interface ZipEntry {
  name: string;
  method: number;
  compressedSize: number;
  localOffset: number;
}

function u16(b: DataView, o: number): number {
  return b.getUint16(o, true);
}
function u32(b: DataView, o: number): number {
  return b.getUint32(o, true);
}
function u64(b: DataView, o: number): number {
  return Number(b.getBigUint64(o, true));
}

/** The central directory of a zip: one entry per member. */
function zipEntries(bytes: Uint8Array, file: string): ZipEntry[] {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  let eocd = -1;
  for (let i = bytes.length - 22; i >= Math.max(0, bytes.length - 22 - 65557); i--) {
    if (u32(dv, i) === 0x06054b50) {
      eocd = i;
      break;
    }
  }
  if (eocd < 0) throw new NpzFormatError(file, "file", "not a zip (.npz) file: no end-of-central-directory record");
  let count = u16(dv, eocd + 10);
  let cdOffset = u32(dv, eocd + 16);
  const loc64 = eocd - 20;
  if (loc64 >= 0 && u32(dv, loc64) === 0x07064b50) {
    const e64 = u64(dv, loc64 + 8);
    if (u32(dv, e64) === 0x06064b50) {
      count = u64(dv, e64 + 32);
      cdOffset = u64(dv, e64 + 48);
    }
  }
  const out: ZipEntry[] = [];
  let p = cdOffset;
  const dec = new TextDecoder();
  for (let n = 0; n < count; n++) {
    if (p + 46 > bytes.length || u32(dv, p) !== 0x02014b50) throw new NpzFormatError(file, "file", "corrupt zip central directory");
    const method = u16(dv, p + 10);
    let csize = u32(dv, p + 20);
    let usize = u32(dv, p + 24);
    const nameLen = u16(dv, p + 28);
    const extraLen = u16(dv, p + 30);
    const commentLen = u16(dv, p + 32);
    let local = u32(dv, p + 42);
    const name = dec.decode(bytes.subarray(p + 46, p + 46 + nameLen));
    // zip64 extra field: the 64-bit values present are those whose 32-bit field is 0xFFFFFFFF.
    let q = p + 46 + nameLen;
    const end = q + extraLen;
    while (q + 4 <= end) {
      const id = u16(dv, q);
      const len = u16(dv, q + 2);
      if (id === 0x0001) {
        let r = q + 4;
        if (usize === 0xffffffff) (usize = u64(dv, r)), (r += 8);
        if (csize === 0xffffffff) (csize = u64(dv, r)), (r += 8);
        if (local === 0xffffffff) local = u64(dv, r);
      }
      q += 4 + len;
    }
    out.push({ name, method, compressedSize: csize, localOffset: local });
    p = end + commentLen;
  }
  return out;
}

async function inflateRaw(data: Uint8Array): Promise<Uint8Array> {
  const stream = new Blob([data as BlobPart]).stream().pipeThrough(new DecompressionStream("deflate-raw"));
  return new Uint8Array(await new Response(stream).arrayBuffer());
}

async function memberBytes(bytes: Uint8Array, e: ZipEntry, file: string): Promise<Uint8Array> {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const p = e.localOffset;
  if (u32(dv, p) !== 0x04034b50) throw new NpzFormatError(file, e.name, "corrupt zip local header");
  const start = p + 30 + u16(dv, p + 26) + u16(dv, p + 28);
  const raw = bytes.subarray(start, start + e.compressedSize);
  if (e.method === 0) return raw;
  if (e.method === 8) return inflateRaw(raw);
  throw new NpzFormatError(file, e.name, `unsupported zip compression method ${e.method}`);
}

/** Parse one `.npy` buffer. */
export function parseNpy(buf: Uint8Array, file: string, member: string): NpyArray {
  const dv = new DataView(buf.buffer, buf.byteOffset, buf.byteLength);
  if (buf.length < 10 || buf[0] !== 0x93 || new TextDecoder().decode(buf.subarray(1, 6)) !== "NUMPY") {
    throw new NpzFormatError(file, member, "not a .npy array");
  }
  const major = buf[6];
  const hlen = major === 1 ? u16(dv, 8) : u32(dv, 8);
  const hstart = major === 1 ? 10 : 12;
  const header = new TextDecoder(major === 3 ? "utf-8" : "latin1").decode(buf.subarray(hstart, hstart + hlen));
  const descr = /'descr':\s*'([^']+)'/.exec(header)?.[1];
  const fortran = /'fortran_order':\s*(True|False)/.exec(header)?.[1];
  const shapeTxt = /'shape':\s*\(([^)]*)\)/.exec(header)?.[1];
  if (!descr || !fortran || shapeTxt === undefined) throw new NpzFormatError(file, member, `unreadable .npy header ${header.trim()}`);
  const shape = shapeTxt.split(",").map((s) => s.trim()).filter((s) => s.length).map(Number);
  const n = shape.reduce((a, b) => a * b, 1);
  if (fortran === "True" && shape.length > 1) throw new NpzFormatError(file, member, "Fortran-ordered arrays are not supported");
  const off = hstart + hlen;
  const body = buf.slice(off); // aligned copy
  const ab = body.buffer;
  const typed = (ctor: { new (b: ArrayBuffer, o: number, n: number): NpyData; BYTES_PER_ELEMENT: number }): NpyData => {
    if (body.byteLength < n * ctor.BYTES_PER_ELEMENT) throw new NpzFormatError(file, member, "truncated array data");
    return new ctor(ab, 0, n);
  };
  let data: NpyData;
  switch (descr) {
    case "<f8": data = typed(Float64Array); break;
    case "<f4": data = typed(Float32Array); break;
    case "<i4": data = typed(Int32Array); break;
    case "<i2": data = typed(Int16Array); break;
    case "|i1": data = typed(Int8Array); break;
    case "|u1": case "|b1": data = typed(Uint8Array); break;
    case "<u2": data = typed(Uint16Array); break;
    case "<u4": data = typed(Uint32Array); break;
    case "<i8": {
      const big = new BigInt64Array(ab, 0, n);
      const f = new Float64Array(n);
      for (let i = 0; i < n; i++) f[i] = Number(big[i]);
      data = f;
      break;
    }
    default: {
      const m = /^<U(\d+)$/.exec(descr);
      if (!m) throw new NpzFormatError(file, member, `unsupported dtype ${descr}`);
      const width = Number(m[1]);
      const bdv = new DataView(ab);
      const strs: string[] = [];
      for (let i = 0; i < n; i++) {
        let s = "";
        for (let j = 0; j < width; j++) {
          const cp = bdv.getUint32((i * width + j) * 4, true);
          if (cp === 0) break;
          s += String.fromCodePoint(cp);
        }
        strs.push(s);
      }
      data = strs;
    }
  }
  return { dtype: descr, shape, data };
}

/** Every member of an `.npz` file, by name without the `.npy` suffix. */
export async function readNpz(bytes: Uint8Array, file = "model.npz"): Promise<Map<string, NpyArray>> {
  const out = new Map<string, NpyArray>();
  for (const e of zipEntries(bytes, file)) {
    if (!e.name.endsWith(".npy")) continue;
    const name = e.name.slice(0, -4);
    out.set(name, parseNpy(await memberBytes(bytes, e, file), file, name));
  }
  return out;
}
