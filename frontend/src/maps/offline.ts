/**
 * Registers the service worker (public/sw.js) that keeps the floor page and its model for
 * offline use. Only the floor pages register it: the editor and the task pages need the
 * network anyway, and stay free of a worker between them and the server.
 */
let asked = false;

export function keepFloorsOffline(): void {
  if (asked || !("serviceWorker" in navigator) || !window.isSecureContext) return;
  asked = true;
  navigator.serviceWorker.register("/sw.js", { scope: "/" }).catch((err) => console.warn("offline use unavailable:", err));
}

/** Ask the service worker to keep these URLs (and the app shell) for offline use. */
export function keepForOffline(urls: string[]): void {
  if (!("serviceWorker" in navigator) || !window.isSecureContext) return;
  navigator.serviceWorker.ready.then((reg) => reg.active?.postMessage({ type: "keep", urls })).catch(() => undefined);
}
