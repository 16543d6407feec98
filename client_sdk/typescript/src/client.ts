/**
 * The posecast client: a thin WebSocket shell around the pure codec, clock and queue.
 *
 * ```ts
 * const client = await connect("ws://127.0.0.1:8765/", token, { WebSocket });
 * await client.join("lobby", "Ada");              // hello -> welcome
 * client.sendFrame({ head, leftHand, rightHand, waist });
 * for await (const ev of client) { ... }          // poses, presence, errors, reconnects
 * await client.close();                           // bye
 * ```
 *
 * Lifecycle: `connect` opens the socket; `join` says `hello` and resolves with the
 * `welcome` (or rejects with the typed error the server answered). If the connection
 * is later lost, or the server shuts down, the client reconnects with exponential
 * back-off and full jitter, says `hello` again for the same room, name and layout
 * (asking the token source again), and carries on: a `reconnecting` event per attempt,
 * then a `welcome` event with `resumed: true`. Frames sent while disconnected are
 * dropped (`sendFrame` returns `undefined`), and `seq` keeps counting across
 * connections (as in the Python SDK), so a pose's `seq` names one frame sent.
 * Errors that retrying cannot fix (KICKED, REPLACED, UNAUTHENTICATED, FORBIDDEN,
 * ROOM_FULL, ...) end the event stream by throwing that error.
 *
 * Versions: the client offers `posecast.v2, posecast.v1` (or only v1 with
 * `{ protocol: 1 }`) and speaks what the server selects. On v2 it keeps each avatar's
 * skeleton and reference state ({@link AvatarTable}), turns each `poses` message into
 * `pose` events (positions by FK, world and local rotations), sends `resync` when a
 * record cannot be applied, and offers {@link PosecastClient.setPoseRate}. On v1 the
 * same `pose` events come from the server's `pose` messages.
 */

import { AvatarTable } from "./avatars.js";
import { ClockSync } from "./clock.js";
import { decode, encode } from "./codec.js";
import {
  ConfigInvalidError,
  ConnectFailedError,
  ConnectionClosedError,
  errorFromMessage,
  ForbiddenError,
  OutOfRangeError,
  PosecastError,
  ProtocolError,
  ServerShutdownError,
  TokenProviderError,
} from "./errors.js";
import { clearTimer, globalWebSocket, monotonicS, setTimer, type TimerId } from "./env.js";
import { type ClientEvent, EventQueue } from "./events.js";
import {
  DEFAULT_LIMITS,
  type Layout,
  type Limits,
  MAX_TIME_S,
  type Member,
  type Message,
  type Pose,
  POSE_RATES_HZ,
  MAX_FORECAST_MS,
  PROTOCOL_V1,
  PROTOCOL_V2,
  type Role,
  seqNext,
  SUBPROTOCOL,
  SUBPROTOCOL_V2,
  type Welcome,
} from "./messages.js";
import { type SitesInput, toSites, type TrackerSet, trackerSetOf } from "./sites.js";
import { type FrameInput, toTrackers } from "./trackers.js";

/** The members of a WebSocket the client uses (browser `WebSocket`, `ws`, undici). */
export interface WebSocketLike {
  binaryType: string;
  readonly readyState: number;
  readonly protocol: string;
  send(data: Uint8Array): void;
  close(code?: number, reason?: string): void;
  onopen: ((ev: unknown) => void) | null;
  onmessage: ((ev: { readonly data: unknown }) => void) | null;
  onclose: ((ev: { readonly code: number; readonly reason: string }) => void) | null;
  onerror: ((ev: unknown) => void) | null;
}

/** A WebSocket class: `globalThis.WebSocket` in browsers, or `WebSocket` from `ws` in Node. */
export type WebSocketConstructor = abstract new (url: string, protocols?: string[]) => object;

/**
 * A join token, or a function that fetches a fresh one (asked again on each reconnect).
 * A function that throws gives {@link TokenProviderError}, retried on a rejoin; one
 * that returns no token, {@link ConfigInvalidError}, which ends the session.
 */
export type TokenSource = string | (() => string | Promise<string>);

export interface ReconnectOptions {
  /** Back-off before the first retry, seconds (before jitter). Default 0.25. */
  readonly initialDelayS?: number;
  /** Longest back-off, seconds. Default 10. */
  readonly maxDelayS?: number;
  /** Back-off growth per failed attempt. Default 2. */
  readonly factor?: number;
  /** Consecutive failed attempts before giving up. Default Infinity. */
  readonly maxAttempts?: number;
}

export interface ConnectOptions {
  /** The WebSocket class; default `globalThis.WebSocket` (browsers, Node >= 22). */
  readonly WebSocket?: WebSocketConstructor;
  /** Reconnect after a lost connection (default on), or `false`. */
  readonly reconnect?: boolean | ReconnectOptions;
  /** Seconds between clock-sync pings once joined; 0 turns them off. Default 2. */
  readonly pingIntervalS?: number;
  /** Seconds to wait for the socket to open, and for the `welcome`. Default 10. */
  readonly timeoutS?: number;
  /** Non-pose events kept for a reader that falls behind. Default 1024. */
  readonly maxQueuedEvents?: number;
  /** The client's monotonic clock in seconds. Default `performance.now() / 1000`. */
  readonly clock?: () => number;
  /** Random numbers in [0, 1) for the back-off jitter. Default `Math.random`. */
  readonly random?: () => number;
  /** The highest protocol to offer: 2 (default: `posecast.v2, posecast.v1`) or 1 (v1 only). */
  readonly protocol?: 1 | 2;
}

export interface JoinOptions {
  /** Frames per second this client will send (announced in `hello`). Absent: 60. */
  readonly rateHz?: number;
  /** Backends only: further rooms to watch. */
  readonly watch?: readonly string[];
  /** v2: poses per second wanted, 60, 30, 20 or 15 (ignored by a v1 server). Absent: 60. */
  readonly poseRateHz?: number;
  /**
   * v2: poses forecast this many ms ahead, 0 to 100, to cancel this client's network and
   * render delay (ignored by a v1 server). The server rounds it to whole ticks
   * (`welcome.forecast_ms`) and stamps each pose's `t` that far past its tick. Absent: 0.
   */
  readonly forecastMs?: number;
}

export type ClientState = "open" | "joining" | "joined" | "reconnecting" | "closed";

/** Codes a reconnect can cure: the server went away or gave up on this connection. */
const RETRYABLE_CODES: ReadonlySet<string> = new Set([
  "CONNECTION_CLOSED",
  "TOKEN_PROVIDER_FAILED", // the token function threw: its backend may be back soon
  "SERVER_SHUTDOWN",
  "TIMED_OUT",
  "SLOW_CONSUMER",
  "INTERNAL",
]);
const PING_BURST = 4; // pings right after each welcome, so the clock converges at once
const PING_BURST_GAP_S = 0.05;
const RESYNC_GAP_S = 0.25; // at most one automatic resync this often (the server rate-limits them)
const WS_OPEN = 1;
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
 * The {@link ConnectFailedError} for a socket that closed before it opened: its reason
 * and hint from the error event before it, where the WebSocket class tells (`ws` and
 * Node's WebSocket give the cause: ECONNREFUSED, ENOTFOUND, a TLS code, "Unexpected
 * server response: 429"; a browser tells nothing).
 */
function connectFailure(url: string, errorEvent: unknown, closeCode: number): ConnectFailedError {
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

/**
 * Open a WebSocket to a posecast server (offering `posecast.v2, posecast.v1`). Resolves
 * once the socket is open; call {@link PosecastClient.join} next.
 *
 * @param url e.g. `wss://host/v1` (the path is up to the deployment)
 * @param token the join token, or a function returning a fresh one
 * @throws ConfigInvalidError before dialing: a URL that is not `ws://` or `wss://` with
 *   a host (`http://...`, `host:port`), or no token (`undefined` from an unset
 *   environment variable, `""`, neither a string nor a function)
 * @throws ConnectFailedError the server cannot be reached or refused the upgrade
 *   (`url`, `reason`, `hint`, `status` where the WebSocket class tells it)
 */
export async function connect(
  url: string,
  token: TokenSource,
  options: ConnectOptions = {},
): Promise<PosecastClient> {
  const client = new PosecastClient(url, token, options);
  await client.open();
  return client;
}

export class PosecastClient implements AsyncIterable<ClientEvent> {
  /** Clock sync from ping/pong: `clock.toClient(pose.t)`, `clock.offsetS`, `clock.rttS`. */
  readonly clock = new ClockSync();
  private readonly queue: EventQueue;
  private readonly now: () => number;
  private readonly WebSocketClass: new (url: string, protocols?: string[]) => WebSocketLike;
  private readonly reconnectOptions: Required<ReconnectOptions> | undefined;
  private ws: WebSocketLike | undefined;
  private generation = 0;
  private stateNow: ClientState = "open";
  private joinArgs: { room: string; name: string; layout?: string; options: JoinOptions } | undefined;
  /** The player's tracker set, when it joined with one: frames then carry `sites`. */
  private trackerSet: TrackerSet | undefined;
  private welcomeNow: Welcome | undefined;
  private limitsNow: Limits = DEFAULT_LIMITS;
  private readonly membersNow = new Map<string, Member>();
  private readonly posesNow = new Map<string, Pose>();
  private readonly avatars = new AvatarTable();
  private versionNow: number = PROTOCOL_V2;
  private poseRateHz: number | undefined;
  private forecastMs: number | undefined;
  private lastResyncT = -Infinity;
  private badRecordsNow = 0;
  private seq = 0;
  private lastFrameT = 0;
  private pending:
    | { resolve(w: Welcome): void; reject(e: PosecastError): void; timer: TimerId }
    | undefined;
  private fatal: PosecastError | undefined;
  private pingTimer: TimerId | undefined;
  private sleepTimer: { id: TimerId; wake(): void } | undefined;
  private closing = false;
  private closed: Promise<void> | undefined;

  /** The server's URL, as {@link checkUrl} gave it (leading and trailing whitespace dropped). */
  readonly url: string;

  /** Use {@link connect}. */
  constructor(
    url: string,
    private readonly token: TokenSource,
    private readonly options: ConnectOptions = {},
  ) {
    this.url = checkUrl(url);
    checkToken(token);
    const ctor = options.WebSocket ?? globalWebSocket();
    if (typeof ctor !== "function") {
      throw new TypeError(
        "no global WebSocket (Node < 22): pass { WebSocket } from the 'ws' package",
      );
    }
    this.WebSocketClass = ctor as new (url: string, protocols?: string[]) => WebSocketLike;
    this.queue = new EventQueue(options.maxQueuedEvents ?? 1024);
    this.now = options.clock ?? monotonicS;
    const r = options.reconnect ?? true;
    this.reconnectOptions =
      r === false
        ? undefined
        : {
            initialDelayS: 0.25,
            maxDelayS: 10,
            factor: 2,
            maxAttempts: Infinity,
            ...(r === true ? {} : r),
          };
  }

  // --- state ------------------------------------------------------------------------------

  get state(): ClientState {
    return this.stateNow;
  }

  /** The latest `welcome` (a resume replaces it). */
  get welcome(): Welcome | undefined {
    return this.welcomeNow;
  }

  /** This connection's player id (from the welcome). */
  get player(): string | undefined {
    return this.welcomeNow?.player;
  }

  get role(): Role | undefined {
    return this.welcomeNow?.role;
  }

  /** The limits in force (the v1 defaults until the welcome). */
  get limits(): Limits {
    return this.limitsNow;
  }

  /** The players in the room now, by id (kept up to date from presence). */
  get members(): ReadonlyMap<string, Member> {
    return this.membersNow;
  }

  /** The newest pose of each player, by id, whether or not the events are read. */
  get poses(): ReadonlyMap<string, Pose> {
    return this.posesNow;
  }

  /** The protocol this connection speaks: 2, or 1 when the server selected `posecast.v1`. */
  get version(): number {
    return this.versionNow;
  }

  /** v2: the bone offsets of `player`, metres, 19 x 3 (PELVIS zero), as last announced. */
  skeletonOf(player: string): Float64Array | undefined {
    return this.avatars.offsetsOf(player);
  }

  /** v2: `poses` messages cut short by a record that could not be applied (each sent a resync). */
  get badRecords(): number {
    return this.badRecordsNow;
  }

  /** Events dropped because the reader fell behind (never poses: those coalesce). */
  get droppedEvents(): number {
    return this.queue.dropped;
  }

  // --- the public calls ---------------------------------------------------------------------

  /** Open the socket (called by {@link connect}). */
  async open(): Promise<void> {
    await this.openSocket();
  }

  /**
   * Say `hello` and wait for the `welcome`.
   *
   * @param room the room to join (the token must allow it)
   * @param name display name shown to the others (1 to 64 UTF-8 bytes)
   * @param layout tracked points; absent, the server takes `hmd3+waist`. A tracker set
   *   (`sites.ts`, e.g. `"head,left_hand,right_hand,waist,left_foot,right_foot"`) is
   *   served where the server runs the `sites` model; {@link sendFrame} then takes a
   *   {@link SitesInput} and sends one row per site of the set.
   * @throws ProtocolError the server's answer (e.g. UnauthenticatedError, RoomFullError)
   * @throws ConnectionClosedError the socket closed or no welcome came in `timeoutS`
   * @throws TokenProviderError the token function threw (`cause`)
   * @throws ConfigInvalidError the token function returned no token
   * @throws RangeError `layout` names no layout or tracker set (nothing is sent)
   * @throws OutOfRangeError `options.forecastMs` outside 0-100 (nothing is sent)
   */
  async join(
    room: string,
    name: string,
    layout?: Layout | string,
    options: JoinOptions = {},
  ): Promise<Welcome> {
    if (this.joinArgs !== undefined) throw new Error("join() was already called on this client");
    if (this.stateNow !== "open") throw new ConnectionClosedError("the client is closed");
    if (options.forecastMs !== undefined) checkForecast(options.forecastMs);
    this.trackerSet = trackerSetOf(layout);
    // hmd3+waist is what an absent layout means: leave it out, as the Python SDK does.
    this.joinArgs =
      layout === undefined || layout === "hmd3+waist"
        ? { room, name, options }
        : { room, name, layout, options };
    this.stateNow = "joining";
    try {
      const welcome = await this.handshake();
      this.joined(welcome, false);
      return welcome;
    } catch (err) {
      this.ws?.close(1000, "join failed");
      this.finish(undefined);
      throw err;
    }
  }

  /**
   * Send one tracker frame (players only). Returns its `seq`, or `undefined` when it
   * was dropped because the client is reconnecting (a newer frame supersedes it; its
   * `seq` is used up all the same). `seq` keeps counting across reconnects, so a
   * pose's `seq` always names one frame this client sent.
   *
   * @param input the four slots by name, or (a player that joined with a tracker
   *   set) every site of the set by name, in any order ({@link SitesInput}).
   * @throws OutOfRangeError, NotNormalisedError a tracked slot is unusable (see
   *   `toTrackers`, `toSites`); nothing is sent.
   * @throws RangeError `t` outside [0, 1e12] s or before the previous frame's; an
   *   inertial site given a position or a positional one an acceleration.
   */
  sendFrame(input: FrameInput | SitesInput): number | undefined {
    if (this.welcomeNow !== undefined && this.welcomeNow.role !== "player") {
      throw new ForbiddenError(`a ${this.welcomeNow.role} may not send frames`);
    }
    const set = this.trackerSet;
    const rows = set ? toSites(set, input) : undefined;
    const { trackers, valid } = rows ? { trackers: undefined, valid: rows.valid } : toTrackers(input as FrameInput);
    // No `t`: now, or the last frame's if that is later (a WebXR frame's
    // predictedDisplayTime is ahead of now; the next unstamped frame must not be refused).
    const t = input.t ?? Math.max(this.now(), this.lastFrameT);
    if (!(t >= this.lastFrameT && t <= MAX_TIME_S)) {
      throw new RangeError(`frame time ${t} s is outside [${this.lastFrameT}, ${MAX_TIME_S}]`);
    }
    const seq = this.seq;
    this.seq = seqNext(seq);
    if (this.stateNow !== "joined") return undefined;
    this.lastFrameT = t;
    const frame: Message = rows
      ? { type: "frame", seq, t, sites: rows.sites, valid }
      : { type: "frame", seq, t, trackers: trackers!, valid };
    return this.send(frame) ? seq : undefined;
  }

  /**
   * Calibrate the avatar: by standing height in metres (floor to the top of the head,
   * 0.9 to 2.5), or by a frame of the user standing in a T-pose (all four trackers,
   * or every site of the player's tracker set). False when not connected.
   */
  calibrate(how: { readonly heightM: number } | { readonly tpose: FrameInput | SitesInput }): boolean {
    if ("heightM" in how) return this.send({ type: "calibrate", height_m: how.heightM });
    const set = this.trackerSet;
    if (set) return this.send({ type: "calibrate", tpose: true, sites: toSites(set, how.tpose).sites });
    return this.send({ type: "calibrate", tpose: true, trackers: toTrackers(how.tpose as FrameInput).trackers });
  }

  /**
   * v2: receive `rateHz` poses a second from now on (60, 30, 20 or 15), and after a
   * reconnect too. False when not connected, or when the server speaks only v1 (the
   * rate is kept for a later v2 connection).
   *
   * @throws OutOfRangeError another rate; nothing is sent.
   */
  setPoseRate(rateHz: number): boolean {
    if (!(POSE_RATES_HZ as readonly number[]).includes(rateHz)) {
      throw new OutOfRangeError(`pose rate ${rateHz} Hz: not 60, 30, 20 or 15`, { field: "rate_hz" });
    }
    this.poseRateHz = rateHz;
    if (this.versionNow < PROTOCOL_V2 || this.stateNow !== "joined") return false;
    return this.send({ type: "pose_rate", rate_hz: rateHz });
  }

  /**
   * v2: receive poses forecast `ms` (0 to 100) ahead from now on, 0 for none, and after a
   * reconnect too. False when not connected, or when the server speaks only v1.
   *
   * @throws OutOfRangeError `ms` outside 0-100; nothing is sent.
   */
  setForecast(ms: number): boolean {
    checkForecast(ms);
    this.forecastMs = ms;
    if (this.versionNow < PROTOCOL_V2 || this.stateNow !== "joined") return false;
    return this.send({ type: "forecast", ms });
  }

  /** v2: ask for a keyframe of every avatar with the next poses. False on v1 or when not connected. */
  resync(): boolean {
    if (this.versionNow < PROTOCOL_V2 || this.stateNow !== "joined") return false;
    this.lastResyncT = this.now();
    return this.send({ type: "resync" });
  }

  /** Send any message as is (backends: `selector`, `kick`). False when not connected. */
  send(msg: Message): boolean {
    const ws = this.ws;
    if (ws === undefined || ws.readyState !== WS_OPEN) return false;
    ws.send(encode(msg));
    return true;
  }

  /**
   * Say `bye` and close. The event stream ends (without an error). Resolves once the
   * socket has closed, or after `timeoutS`. Note that the server remembers the token
   * of a session that said `bye`: the same token cannot join again.
   */
  close(reason = "bye"): Promise<void> {
    if (this.closed !== undefined) return this.closed;
    this.closing = true;
    this.sleepTimer?.wake();
    const ws = this.ws;
    this.closed = new Promise<void>((resolve) => {
      if (ws === undefined || ws.readyState > WS_OPEN) {
        resolve();
        return;
      }
      const timer = setTimer(resolve, this.options.timeoutS ?? 10);
      const previous = ws.onclose;
      ws.onclose = (ev) => {
        previous?.(ev);
        clearTimer(timer);
        resolve();
      };
      if (ws.readyState === WS_OPEN && this.joinArgs !== undefined) {
        this.send({ type: "bye", reason });
      }
      ws.close(1000, reason);
    });
    this.finish(undefined);
    return this.closed;
  }

  /** The event stream: poses, presence, non-fatal errors, welcomes, reconnects. */
  events(): AsyncIterableIterator<ClientEvent> {
    const queue = this.queue;
    return {
      next: () => queue.next(),
      return: async () => ({ value: undefined, done: true }),
      [Symbol.asyncIterator]() {
        return this;
      },
    };
  }

  [Symbol.asyncIterator](): AsyncIterator<ClientEvent> {
    return this.events();
  }

  // --- one socket -----------------------------------------------------------------------------

  private openSocket(): Promise<WebSocketLike> {
    const gen = ++this.generation;
    const offered = this.options.protocol === PROTOCOL_V1 ? [SUBPROTOCOL] : [SUBPROTOCOL_V2, SUBPROTOCOL];
    let ws: WebSocketLike;
    try {
      ws = new this.WebSocketClass(this.url, offered);
    } catch (err) {
      // checkUrl passed it, so the host's own rule: e.g. a page served over https may
      // not open a ws:// URL (SecurityError).
      const why = err instanceof Error ? err.message : String(err);
      throw new ConfigInvalidError(
        `the WebSocket class refused ${JSON.stringify(this.url)} (${why})`,
        "a page served over https needs a wss:// URL",
        { cause: err },
      );
    }
    ws.binaryType = "arraybuffer";
    this.ws = ws;
    this.fatal = undefined;
    return new Promise<WebSocketLike>((resolve, reject) => {
      const timeoutS = this.options.timeoutS ?? 10;
      const timer = setTimer(() => {
        ws.close();
        reject(
          new ConnectFailedError(
            this.url,
            `no WebSocket handshake within ${timeoutS} s`,
            "is the host reachable from here (a firewall, a VPN)? options.timeoutS allows longer",
          ),
        );
      }, timeoutS);
      let errorEvent: unknown;
      ws.onerror = (ev) => {
        errorEvent = ev; // a close event follows every error; this one says why
      };
      ws.onclose = (ev) => {
        clearTimer(timer);
        reject(connectFailure(this.url, errorEvent, ev.code));
      };
      ws.onopen = () => {
        clearTimer(timer);
        ws.onmessage = (ev) => this.onData(gen, ev.data);
        ws.onclose = (ev) => this.onClose(gen, ev.code, ev.reason);
        if (!offered.includes(ws.protocol)) {
          ws.close(1002, "subprotocol");
          reject(new ConnectionClosedError(`server did not select ${offered.join(" or ")}`, 1002));
          return;
        }
        this.versionNow = ws.protocol === SUBPROTOCOL_V2 ? PROTOCOL_V2 : PROTOCOL_V1;
        resolve(ws);
      };
    });
  }

  private async handshake(): Promise<Welcome> {
    const args = this.joinArgs!;
    let token: unknown = this.token;
    if (typeof this.token === "function") {
      try {
        token = await this.token();
      } catch (err) {
        throw new TokenProviderError(`the token function threw ${describeThrown(err)}`, { cause: err });
      }
    }
    if (typeof token !== "string" || token.trim() === "") {
      throw new ConfigInvalidError(
        `the token function returned ${what(token)}`,
        "it must return the join token, a non-empty string",
      );
    }
    return new Promise<Welcome>((resolve, reject) => {
      const timer = setTimer(() => {
        this.pending = undefined;
        this.ws?.close(1000, "no welcome");
        reject(new ConnectionClosedError("no welcome in time"));
      }, this.options.timeoutS ?? 10);
      this.pending = { resolve, reject, timer };
      const poseRate = args.options.poseRateHz ?? this.poseRateHz;
      const forecast = this.forecastMs ?? args.options.forecastMs;
      const hello = {
        type: "hello",
        version: this.versionNow,
        token,
        room: args.room,
        name: args.name,
        ...(args.layout === undefined ? {} : { layout: args.layout }),
        ...(args.options.rateHz === undefined ? {} : { rate_hz: args.options.rateHz }),
        ...(args.options.watch === undefined ? {} : { watch: args.options.watch }),
        ...(poseRate === undefined || this.versionNow < PROTOCOL_V2 ? {} : { pose_rate_hz: poseRate }),
        ...(!forecast || this.versionNow < PROTOCOL_V2 ? {} : { forecast_ms: forecast }),
      } as const;
      if (!this.send(hello)) {
        clearTimer(timer);
        this.pending = undefined;
        reject(new ConnectionClosedError("the socket closed before hello"));
      }
    });
  }

  private onData(gen: number, data: unknown): void {
    if (gen !== this.generation) return;
    let bytes: Uint8Array;
    if (data instanceof ArrayBuffer) bytes = new Uint8Array(data);
    else if (ArrayBuffer.isView(data)) {
      bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
    } else return; // posecast servers send binary messages only
    let msg: Message;
    try {
      msg = decode(bytes, { limits: this.limitsNow, version: this.versionNow });
    } catch (err) {
      if (err instanceof ProtocolError) this.queue.push({ type: "error", error: err });
      return;
    }
    this.onMessage(msg);
  }

  private onMessage(msg: Message): void {
    switch (msg.type) {
      case "welcome": {
        const pending = this.pending;
        this.pending = undefined;
        // Synchronously, before the next message: poses may follow at once.
        this.avatars.reset(this.versionNow >= PROTOCOL_V2 ? msg.members : []);
        if (pending !== undefined) {
          clearTimer(pending.timer);
          pending.resolve(msg);
        }
        return;
      }
      case "pose":
        this.onPose(msg);
        return;
      case "poses": {
        const { poses, error } = this.avatars.poses(msg);
        for (const pose of poses) this.onPose(pose);
        if (error !== undefined) {
          this.badRecordsNow++;
          // The records after the bad one were skipped: their references are stale now.
          // Drop every reference so no delta applies to a stale one (as the C# SDK does).
          this.avatars.dropState();
          this.queue.push({ type: "error", error });
          if (this.now() - this.lastResyncT >= RESYNC_GAP_S) this.resync();
        }
        return;
      }
      case "skeleton":
        this.avatars.skeleton(msg);
        return;
      case "presence":
        this.avatars.presence(msg);
        if (msg.room === this.welcomeNow?.room) {
          if (msg.event === "leave") {
            this.membersNow.delete(msg.player);
            this.posesNow.delete(msg.player);
          } else {
            const known = this.membersNow.get(msg.player);
            this.membersNow.set(
              msg.player,
              msg.avatarId !== undefined && msg.skeleton !== undefined
                ? { player: msg.player, name: msg.name, avatarId: msg.avatarId, skeleton: msg.skeleton }
                : { ...known, player: msg.player, name: msg.name },
            );
          }
        }
        this.queue.push(msg);
        return;
      case "pong":
        this.clock.add(msg.t0, msg.t1, msg.t2, this.now());
        return;
      case "error": {
        const error = errorFromMessage(msg);
        if (!error.fatal) this.queue.push({ type: "error", error });
        else this.fatal = error;
        if (this.pending !== undefined && error.fatal) {
          clearTimer(this.pending.timer);
          this.pending.reject(error);
          this.pending = undefined;
        }
        return;
      }
      case "bye":
        if (msg.reason === ServerShutdownError.code) {
          this.fatal = new ServerShutdownError("the server is shutting down", { fatal: true });
        }
        return;
      default:
        return; // client-bound messages only; anything else is ignored
    }
  }

  private onPose(pose: Pose): void {
    this.posesNow.set(pose.player, pose);
    this.queue.push(pose);
  }

  private onClose(gen: number, code: number, reason: string): void {
    if (gen !== this.generation) return;
    clearTimer(this.pingTimer);
    const cause =
      this.fatal ?? new ConnectionClosedError(`connection closed (${code} ${reason})`, code, reason);
    if (this.pending !== undefined) {
      clearTimer(this.pending.timer);
      this.pending.reject(cause);
      this.pending = undefined;
      return; // join() or the reconnect loop decides
    }
    if (this.closing || this.stateNow !== "joined") return;
    if (this.retryable(cause)) void this.reconnect(cause);
    else this.finish(this.fatal === undefined && code === 1000 ? undefined : cause);
  }

  // --- joined, resumed, closed ----------------------------------------------------------------

  private joined(welcome: Welcome, resumed: boolean): void {
    this.welcomeNow = welcome;
    this.limitsNow = welcome.limits;
    this.membersNow.clear();
    for (const m of welcome.members) this.membersNow.set(m.player, m);
    for (const player of [...this.posesNow.keys()]) {
      if (!this.membersNow.has(player)) this.posesNow.delete(player);
    }
    if (resumed) this.clock.reset(); // it may be a new server process, with a new epoch
    this.stateNow = "joined";
    this.queue.push({ type: "welcome", welcome, resumed });
    this.schedulePings(PING_BURST);
  }

  private schedulePings(burst: number): void {
    const every = this.options.pingIntervalS ?? 2;
    if (burst <= 0 && !(every > 0)) return;
    const gen = this.generation;
    this.pingTimer = setTimer(
      () => {
        if (gen !== this.generation || this.stateNow !== "joined") return;
        this.send({ type: "ping", t0: this.now() });
        this.schedulePings(burst - 1);
      },
      burst > 0 ? (burst === PING_BURST ? 0 : PING_BURST_GAP_S) : every,
      true,
    );
  }

  private retryable(err: unknown): boolean {
    if (this.reconnectOptions === undefined || this.closing) return false;
    if (!(err instanceof PosecastError)) return false;
    if (err.code === "TOKEN_EXPIRED") return typeof this.token === "function";
    return RETRYABLE_CODES.has(err.code);
  }

  private async reconnect(cause: PosecastError): Promise<void> {
    const opts = this.reconnectOptions!;
    this.stateNow = "reconnecting";
    for (let attempt = 1; !this.closing; attempt++) {
      if (attempt > opts.maxAttempts) {
        this.finish(cause);
        return;
      }
      const cap = Math.min(opts.maxDelayS, opts.initialDelayS * opts.factor ** (attempt - 1));
      const delayS = cap * (this.options.random ?? Math.random)(); // full jitter
      this.queue.push({ type: "reconnecting", attempt, delayS, cause });
      await this.sleep(delayS);
      if (this.closing) break;
      try {
        await this.openSocket();
        const welcome = await this.handshake();
        this.joined(welcome, true);
        return;
      } catch (err) {
        this.ws?.close();
        if (!this.retryable(err)) {
          this.finish(err);
          return;
        }
        cause = err as PosecastError;
      }
    }
    this.finish(undefined);
  }

  private sleep(seconds: number): Promise<void> {
    return new Promise<void>((resolve) => {
      const wake = (): void => {
        clearTimer(this.sleepTimer?.id);
        this.sleepTimer = undefined;
        resolve();
      };
      this.sleepTimer = { id: setTimer(wake, seconds), wake };
    });
  }

  private finish(error: unknown): void {
    if (this.stateNow === "closed") return;
    this.stateNow = "closed";
    clearTimer(this.pingTimer);
    this.generation++; // late events from the last socket are ignored from here on
    this.queue.end(error);
  }
}

function checkForecast(ms: number): void {
  if (!(ms >= 0 && ms <= MAX_FORECAST_MS)) {
    throw new OutOfRangeError(`forecast ${ms} ms: not within 0-${MAX_FORECAST_MS}`, { field: "ms" });
  }
}
