/**
 * The page's address and its elements: the room, the token from the address (removed
 * from the address bar once read), the WebSocket URL, and the DOM lookups the other
 * modules share.
 *
 * Token: `#token=` (preferred: a fragment never reaches the server or its logs) or
 * `?token=` in the page URL. Without one, `network.ts` asks the server's dev-only
 * `token` endpoint.
 */

export const params = new URLSearchParams(location.search);
const fragment = new URLSearchParams(location.hash.slice(1));
export const room = params.get("room") || "demo";
export const urlToken = fragment.get("token") ?? params.get("token");
if (params.has("token")) {
  // Keep the token out of the address bar, history and bookmarks from here on.
  params.delete("token");
  history.replaceState(null, "", `${location.pathname}?${params}${location.hash}`);
}
/** The page lives at <prefix>/viewer/; the WebSocket at <prefix>/ (or ?ws=). */
const prefix = location.pathname.replace(/viewer\/?$/, "");
export const wsUrl =
  params.get("ws") ?? `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}${prefix}`;

/** The page's element with id `id`. */
export const $ = <T extends HTMLElement>(id: string): T => document.getElementById(id) as T;
