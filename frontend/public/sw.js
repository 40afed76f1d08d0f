/*
 * posefix service worker: the floor page keeps working offline once it and its model were
 * loaded. The app shell (index.html, hashed assets) and the few GETs the floor page needs
 * to start (who is signed in, the floor, its image and its model) are answered from the
 * network when it answers, else from the copy kept the last time. Everything else (and
 * every write) goes to the network untouched. Signing in or out drops the kept API copies.
 * The page also names what it shows ({type: "keep", urls}) so that a first visit, made
 * before this worker controlled the page, is kept too: the shell with its assets, and the
 * given API URLs.
 */
const SHELL = "posefix-shell-v1";
const DATA = "posefix-data-v1";
const OFFLINE_API = [
  /^\/api\/v1\/auth\/me$/,
  /^\/api\/v1\/floorplans\/\d+$/,
  /^\/api\/v1\/floorplans\/\d+\/(model|image)$/,
];

self.addEventListener("install", (e) => {
  e.waitUntil(self.skipWaiting());
});

self.addEventListener("activate", (e) => {
  e.waitUntil(
    caches.keys()
      .then((keys) => Promise.all(keys.filter((k) => k.startsWith("posefix-") && k !== SHELL && k !== DATA).map((k) => caches.delete(k))))
      .then(() => self.clients.claim()),
  );
});

async function networkFirst(request, cacheName, key) {
  const cache = await caches.open(cacheName);
  try {
    const response = await fetch(request);
    if (response.ok) await cache.put(key || request, response.clone());
    return response;
  } catch (err) {
    const kept = await cache.match(key || request);
    if (kept) return kept;
    throw err;
  }
}

async function cacheFirst(request, cacheName) {
  const cache = await caches.open(cacheName);
  const kept = await cache.match(request);
  if (kept) return kept;
  const response = await fetch(request);
  if (response.ok) await cache.put(request, response.clone());
  return response;
}

self.addEventListener("fetch", (e) => {
  const request = e.request;
  const url = new URL(request.url);
  if (url.origin !== self.location.origin) return;
  if (request.method === "POST" && /^\/api\/v1\/auth\/(login|logout)$/.test(url.pathname)) {
    e.waitUntil(caches.delete(DATA));
    return;
  }
  if (request.method !== "GET") return;
  if (request.mode === "navigate") return e.respondWith(networkFirst(request, SHELL, "/"));
  if (url.pathname.startsWith("/assets/")) return e.respondWith(cacheFirst(request, SHELL));
  if (OFFLINE_API.some((r) => r.test(url.pathname))) return e.respondWith(networkFirst(request, DATA));
});

async function keepShell() {
  const cache = await caches.open(SHELL);
  const response = await fetch("/", { cache: "no-cache" });
  if (!response.ok) return;
  const html = await response.clone().text();
  await cache.put("/", response);
  const assets = [...html.matchAll(/(?:src|href)="(\/assets\/[^"]+)"/g)].map((m) => m[1]);
  await Promise.all(assets.map(async (a) => (await cache.match(a)) || cache.add(a)));
}

async function keepData(urls) {
  const cache = await caches.open(DATA);
  await Promise.all(urls.filter((u) => OFFLINE_API.some((r) => r.test(new URL(u, self.location.origin).pathname))).map(async (u) => {
    const response = await fetch(u, { credentials: "same-origin" });
    if (response.ok) await cache.put(u, response);
  }));
}

self.addEventListener("message", (e) => {
  if (e.data && e.data.type === "keep" && Array.isArray(e.data.urls)) {
    e.waitUntil(Promise.all([keepShell(), keepData(e.data.urls)]).catch(() => undefined));
  }
});
