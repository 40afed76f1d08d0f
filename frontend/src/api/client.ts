/**
 * The typed API client: openapi-fetch over the types generated from the server's OpenAPI
 * spec (`npm run gen:api` -> schema.d.ts). `unwrap` turns its `{data, error, response}` into
 * data or an ApiError (server body, or a network failure) so the UI can say plainly what
 * went wrong.
 */
import createClient from "openapi-fetch";
import { ApiError, apiErrorFrom, networkError } from "./errors";
import type { components, paths } from "./schema";

export type Schemas = components["schemas"];

export const client = createClient<paths>({ baseUrl: "", credentials: "same-origin", headers: { Accept: "application/json" } });

/** Await an openapi-fetch call; return its data or throw an ApiError. */
export async function unwrap<T>(call: Promise<{ data?: T; error?: unknown; response: Response }>): Promise<T> {
  let r: { data?: T; error?: unknown; response: Response };
  try {
    r = await call;
  } catch (err) {
    if (err instanceof DOMException && err.name === "AbortError") throw err;
    throw networkError(err);
  }
  if (!r.response.ok) throw apiErrorFrom(r.response.status, r.error, r.response.statusText);
  return r.data as T;
}

export { ApiError };

