// Replace dist/ with the fresh build in .dist-tmp/ by two renames, so a running server
// (which serves dist/ at "/") never sees a half-emptied directory during a rebuild.
import { existsSync, renameSync, rmSync } from "node:fs";
import { dirname, resolve } from "node:path";
import { fileURLToPath } from "node:url";

const root = resolve(dirname(fileURLToPath(import.meta.url)), "..");
const fresh = resolve(root, ".dist-tmp");
const dist = resolve(root, "dist");
const old = resolve(root, ".dist-old");
if (!existsSync(resolve(fresh, "index.html"))) throw new Error(`${fresh}/index.html missing: the build failed`);
rmSync(old, { recursive: true, force: true });
if (existsSync(dist)) renameSync(dist, old);
renameSync(fresh, dist);
rmSync(old, { recursive: true, force: true });
