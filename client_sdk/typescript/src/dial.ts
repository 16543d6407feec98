/**
 * What the client checks before it dials, and how it explains a dial that failed (pure:
 * no sockets). The Python and C# SDKs take the same URLs and tokens and give the same
 * reasons.
 *
 * - {@link checkUrl}, {@link checkToken}: a {@link ConfigInvalidError} with a hint before
 *   anything is dialed (an `http://` URL, `host:port`, an unset environment variable).
 * - {@link fetchToken}: a fresh token from a token function, for one `hello`.
 * - {@link connectFailure}: the {@link ConnectFailedError} for a socket that closed before
 *   it opened, its reason and hint read from the WebSocket class's error event.
 */

import { ConfigInvalidError, ConnectFailedError, TokenProviderError } from "./errors.js";

/**
 * A join token, or a function that fetches a fresh one (asked again on each reconnect).
 * A function that throws gives {@link TokenProviderError}, retried on a rejoin; one
 * that returns no token, {@link ConfigInvalidError}, which ends the session.
 */
export type TokenSource = string | (() => string | Promise<string>);

const EXAMPLE_URL = "ws://127.0.0.1:8765/";
const TOKEN_HINT =
  "pass the join token: a string your backend minted, or a function returning one; " +
  "an unset environment variable?";
const RUNNING_HINT =
  "is a posecast server running there, and reachable from here? `posecast serve --dev` starts one";
const STATUS_HINTS: ReadonlyMap<number, string> = new Map([
  [429, "this address connected (or broke the protocol) too often: back off, try again later"],
  [503, "the server is starting, busy or full: try again in a moment, with back-off"],
]);

/** What a function threw, for a message: `Error: why`, or the value itself. */
function describeThrown(err: unknown): string {
  return err instanceof Error ? `${err.name}: ${err.message}` : String(err);
}

/** How an unusable argument is named in an error: `undefined`, `an empty string`... */
function what(value: unknown): string {
  if (value === undefined || value === null) return String(value);
  if (typeof value === "string") return value === "" ? "an empty string" : "a blank string";
  return `a value of type ${typeof value}`;
}

/**
 * `url` without leading or trailing whitespace (what the client keeps and dials), if
 * the client can dial it: `ws://` or `wss://` (any case), a host, a port from 1 to
 * 65535 (absent: 80 or 443), no `#fragment`; the Python and C# SDKs take the same.
 *
 * @throws ConfigInvalidError anything else, with a hint (an `http://` URL: its `ws://`
 *   twin; `host:port`: the `ws://` URL).
 */
export function checkUrl(url: unknown): string {
  if (typeof url !== "string" || url.trim() === "") {
    throw new ConfigInvalidError(
      `no server URL (got ${what(url)})`,
      `pass the server's WebSocket URL, such as ${EXAMPLE_URL}; an unset environment variable?`,
    );
  }
  const text = url.trim();
  const m = /^([A-Za-z][A-Za-z0-9+.-]*):(\/\/)?/.exec(text);
  const scheme = m?.[1]?.toLowerCase() ?? "";
  const slashes = m?.[2] !== undefined;
  const quoted = JSON.stringify(url);
  if ((scheme === "http" || scheme === "https") && slashes) {
    const twin = (scheme === "http" ? "ws" : "wss") + text.slice(scheme.length);
    throw new ConfigInvalidError(`${quoted} is an HTTP URL, not a WebSocket one`, `use ${twin}`);
  }
  if ((scheme !== "ws" && scheme !== "wss") || !slashes) {
    const hostPort = !text.includes("://") && !["ws", "wss", "http", "https"].includes(scheme);
    throw new ConfigInvalidError(
      `${quoted} is not a WebSocket URL: it must start with ws:// (wss:// behind TLS)`,
      hostPort ? `did you mean ws://${text}${text.includes("/") ? "" : "/"}?` : `such as ${EXAMPLE_URL}`,
    );
  }
  const authority = text.slice(scheme.length + 3).split(/[/?#]/, 1)[0]!;
  const hostPort = authority.slice(authority.lastIndexOf("@") + 1);
  const bracket = hostPort.startsWith("[") ? hostPort.indexOf("]") + 1 : 0;
  const colon = hostPort.indexOf(":", bracket);
  const host = colon < 0 ? hostPort : hostPort.slice(0, colon);
  const port = colon < 0 ? "" : hostPort.slice(colon + 1);
  if (host === "" || host === "[]") {
    throw new ConfigInvalidError(`${quoted} names no host`, `such as ${EXAMPLE_URL}`);
  }
  if (port !== "" && !(/^[0-9]{1,5}$/.test(port) && Number(port) >= 1 && Number(port) <= 65535)) {
    throw new ConfigInvalidError(`${quoted} has a bad port (${port})`, "a port is a number from 1 to 65535");
  }
  if (text.includes("#")) {
    throw new ConfigInvalidError(
      `${quoted} has a #fragment, which a WebSocket URL may not`,
      "leave out the # and what follows it",
    );
  }
  return text;
}

/**
 * A token the client can send: a non-blank string, or a function (its result is
 * checked at every join).
 *
 * @throws ConfigInvalidError `undefined` (an unset environment variable), `null`, an
 *   empty string, anything else.
 */
export function checkToken(token: unknown): void {
  if (typeof token === "function" || (typeof token === "string" && token.trim() !== "")) return;
  throw new ConfigInvalidError(`no token (got ${what(token)})`, TOKEN_HINT);
}

/**
 * A fresh token from a token function, for one `hello` (a string token is sent as is).
 *
 * @throws TokenProviderError the token function threw (`cause`)
 * @throws ConfigInvalidError the token function returned no token (not a non-blank string)
 */
export async function fetchToken(source: () => string | Promise<string>): Promise<string> {
  let token: unknown;
  try {
    token = await source();
  } catch (err) {
    throw new TokenProviderError(`the token function threw ${describeThrown(err)}`, { cause: err });
  }
  if (typeof token !== "string" || token.trim() === "") {
    throw new ConfigInvalidError(
      `the token function returned ${what(token)}`,
      "it must return the join token, a non-empty string",
    );
  }
  return token;
}

/**
 * The {@link ConnectFailedError} for a socket that closed before it opened: its reason
 * and hint from the error event before it, where the WebSocket class tells (`ws` and
 * Node's WebSocket give the cause: ECONNREFUSED, ENOTFOUND, a TLS code, "Unexpected
 * server response: 429"; a browser tells nothing).
 */
export function connectFailure(url: string, errorEvent: unknown, closeCode: number): ConnectFailedError {
  const ev = (errorEvent ?? {}) as { readonly error?: unknown; readonly message?: unknown };
  const cause = ev.error;
  const sysCode = String((cause as { code?: unknown } | undefined)?.code ?? "");
  const text = String((cause as { message?: unknown } | undefined)?.message ?? ev.message ?? "");
  const http = /Unexpected server response: (\d+)/.exec(text);
  const more = { closeCode, cause };
  if (http !== null) {
    const status = Number(http[1]);
    const hint = STATUS_HINTS.get(status) ?? `is the URL a posecast WebSocket endpoint, such as ${EXAMPLE_URL}?`;
    return new ConnectFailedError(url, `the server refused the WebSocket upgrade with HTTP ${status}`, hint, {
      ...more,
      status,
    });
  }
  if (sysCode === "ECONNREFUSED") {
    return new ConnectFailedError(url, "connection refused (nothing listens at that port)", RUNNING_HINT, more);
  }
  if (sysCode === "ENOTFOUND" || sysCode === "EAI_AGAIN") {
    return new ConnectFailedError(
      url,
      `the host name does not resolve (${sysCode})`,
      "check the host in the URL, and this machine's network",
      more,
    );
  }
  const secure = /^wss:/i.test(url.trim());
  if (/SSL|TLS|CERT|EPROTO/.test(sysCode) || (secure && sysCode === "ECONNRESET")) {
    return new ConnectFailedError(
      url,
      `TLS failed (${text || sysCode})`,
      "does the server speak TLS at that port, with a certificate trusted here? one without TLS takes ws://",
      more,
    );
  }
  return new ConnectFailedError(url, text || `the socket closed (code ${closeCode})`, RUNNING_HINT, more);
}
