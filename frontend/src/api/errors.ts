/** Errors from the API, normalised: the server's `{error, detail}` body, or a network failure. */
export class ApiError extends Error {
  constructor(
    readonly status: number,
    readonly code: string,
    readonly detail: string,
    readonly body: Record<string, unknown> = {},
  ) {
    super(detail || code);
    this.name = "ApiError";
  }

  get isNetwork(): boolean {
    return this.status === 0;
  }
}

/** Build an ApiError from a response status and (possibly non-JSON) body. */
export function apiErrorFrom(status: number, body: unknown, statusText = ""): ApiError {
  if (body && typeof body === "object") {
    const b = body as Record<string, unknown>;
    const code = typeof b.error === "string" ? b.error : `http_${status}`;
    let detail = "";
    if (typeof b.detail === "string") detail = b.detail;
    else if (Array.isArray(b.detail)) detail = b.detail.map((d) => (d && typeof d === "object" && "msg" in d ? String((d as { msg: unknown }).msg) : String(d))).join("; ");
    else if (typeof b.message === "string") detail = b.message;
    return new ApiError(status, code, detail || `${status} ${statusText}`.trim(), b);
  }
  const text = typeof body === "string" && body.length < 300 ? body : "";
  return new ApiError(status, `http_${status}`, text || `The server answered ${status} ${statusText}`.trim());
}

export function networkError(err: unknown): ApiError {
  const why = err instanceof Error ? err.message : String(err);
  return new ApiError(0, "network", `Cannot reach the server (${why}). Check your connection; nothing was lost.`);
}

/** Plain words for an error, for the operator. */
export function describeError(err: unknown): string {
  if (err instanceof ApiError) {
    if (err.isNetwork) return err.detail;
    if (err.status >= 500) return `The server failed (${err.status}): ${err.detail}`;
    return err.detail;
  }
  return err instanceof Error ? err.message : String(err);
}
