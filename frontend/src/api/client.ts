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

/** Routes not (yet) in the generated spec: same error handling, untyped. */
export async function request<T>(method: string, path: string, body?: unknown, headers: Record<string, string> = {}, signal?: AbortSignal): Promise<T> {
  return unwrap<T>(
    fetch(`/api/v1${path}`, {
      method,
      credentials: "same-origin",
      headers: { Accept: "application/json", ...(body === undefined ? {} : { "Content-Type": "application/json" }), ...headers },
      body: body === undefined ? undefined : JSON.stringify(body),
      signal,
    }).then(async (response) => {
      const text = await response.text();
      let data: unknown = text;
      try {
        data = text ? JSON.parse(text) : null;
      } catch {
        /* keep text */
      }
      return response.ok ? { data: data as T, response } : { error: data, response };
    }),
  );
}
