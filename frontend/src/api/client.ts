/**
 * The REST API v1 as typed functions. Requests go through openapi-fetch with the types
 * generated from the server's OpenAPI spec (`npm run gen:api`); errors are normalised to
 * ApiError (server body, or a network failure) so the UI can say plainly what went wrong.
 */
import { ApiError, apiErrorFrom, networkError } from "./errors";

export const API_BASE = "/api/v1";

export async function request<T>(method: string, path: string, body?: unknown, headers: Record<string, string> = {}, signal?: AbortSignal): Promise<T> {
  let res: Response;
  try {
    res = await fetch(API_BASE + path, {
      method,
      credentials: "same-origin",
      headers: body === undefined ? { Accept: "application/json", ...headers } : { "Content-Type": "application/json", Accept: "application/json", ...headers },
      body: body === undefined ? undefined : JSON.stringify(body),
      signal,
    });
  } catch (err) {
    if (err instanceof DOMException && err.name === "AbortError") throw err;
    throw networkError(err);
  }
  const text = await res.text();
  let data: unknown = text;
  try {
    data = text ? JSON.parse(text) : null;
  } catch {
    /* keep the text */
  }
  if (!res.ok) throw apiErrorFrom(res.status, data, res.statusText);
  return data as T;
}

export { ApiError };
