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
 *
 * This module is the public face: what to send (frames, calibration, pose rates) and
 * what is known (state, welcome, members, poses). The connection behind it, across
 * reconnects, is `connection.ts`; the room state it keeps, `room-state.ts`; the URL and
 * token checks and dial failures, `dial.ts`; the back-off, `reconnect.ts`.
 */

import type { ClientState, ConnectOptions, JoinOptions } from "./client-options.js";
import type { ClockSync } from "./clock.js";
import { ClientConnection } from "./connection.js";
import type { TokenSource } from "./dial.js";
import { ForbiddenError, OutOfRangeError } from "./errors.js";
import type { ClientEvent, EventQueue } from "./events.js";
import {
  type Layout,
  type Limits,
  MAX_FORECAST_MS,
  MAX_TIME_S,
  type Member,
  type Message,
  type Pose,
  POSE_RATES_HZ,
  PROTOCOL_V2,
  type Role,
  seqNext,
  type Welcome,
} from "./messages.js";
import type { RoomState } from "./room-state.js";
import { type SitesInput, toSites, type TrackerSet, trackerSetOf } from "./sites.js";
import { type FrameInput, toTrackers } from "./trackers.js";

// The option and socket types are part of the client's API (index.ts exports them from here).
export type { ClientState, ConnectOptions, JoinOptions, ReconnectOptions } from "./client-options.js";
export type { TokenSource } from "./dial.js";
export type { WebSocketConstructor, WebSocketLike } from "./socket.js";

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
  readonly clock: ClockSync;
  /** The server's URL, as `checkUrl` gave it (leading and trailing whitespace dropped). */
  readonly url: string;
  private readonly connection: ClientConnection;
  private readonly room: RoomState;
  private readonly queue: EventQueue;
  /** The player's tracker set, when it joined with one: frames then carry `sites`. */
  private trackerSet: TrackerSet | undefined;
  private seq = 0;
  private lastFrameT = 0;

  /** Use {@link connect}. */
  constructor(url: string, token: TokenSource, options: ConnectOptions = {}) {
    this.connection = new ClientConnection(url, token, options);
    this.clock = this.connection.clock;
    this.url = this.connection.url;
    this.room = this.connection.room;
    this.queue = this.connection.queue;
  }

  // --- state ------------------------------------------------------------------------------

  get state(): ClientState {
    return this.connection.state;
  }

  /** The latest `welcome` (a resume replaces it). */
  get welcome(): Welcome | undefined {
    return this.room.welcome;
  }

  /** This connection's player id (from the welcome). */
  get player(): string | undefined {
    return this.room.welcome?.player;
  }

  get role(): Role | undefined {
    return this.room.welcome?.role;
  }

  /** The limits in force (the v1 defaults until the welcome). */
  get limits(): Limits {
    return this.room.limits;
  }

  /** The players in the room now, by id (kept up to date from presence). */
  get members(): ReadonlyMap<string, Member> {
    return this.room.members;
  }

  /** The newest pose of each player, by id, whether or not the events are read. */
  get poses(): ReadonlyMap<string, Pose> {
    return this.room.poses;
  }

  /** The protocol this connection speaks: 2, or 1 when the server selected `posecast.v1`. */
  get version(): number {
    return this.connection.version;
  }

  /** v2: the bone offsets of `player`, metres, 19 x 3 (PELVIS zero), as last announced. */
  skeletonOf(player: string): Float64Array | undefined {
    return this.room.offsetsOf(player);
  }

  /** v2: `poses` messages cut short by a record that could not be applied (each sent a resync). */
  get badRecords(): number {
    return this.room.badRecords;
  }

  /** Events dropped because the reader fell behind (never poses: those coalesce). */
  get droppedEvents(): number {
    return this.queue.dropped;
  }

  // --- the public calls ---------------------------------------------------------------------

  /** Open the socket (called by {@link connect}). */
  async open(): Promise<void> {
    await this.connection.open();
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
    this.connection.assertJoinable();
    if (options.forecastMs !== undefined) checkForecast(options.forecastMs);
    this.trackerSet = trackerSetOf(layout);
    // hmd3+waist is what an absent layout means: leave it out, as the Python SDK does.
    return this.connection.join(
      layout === undefined || layout === "hmd3+waist" ? { room, name, options } : { room, name, layout, options },
    );
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
    const welcome = this.room.welcome;
    if (welcome !== undefined && welcome.role !== "player") {
      throw new ForbiddenError(`a ${welcome.role} may not send frames`);
    }
    const set = this.trackerSet;
    const rows = set ? toSites(set, input) : undefined;
    const { trackers, valid } = rows ? { trackers: undefined, valid: rows.valid } : toTrackers(input as FrameInput);
    // No `t`: now, or the last frame's if that is later (a WebXR frame's
    // predictedDisplayTime is ahead of now; the next unstamped frame must not be refused).
    const t = input.t ?? Math.max(this.connection.now(), this.lastFrameT);
    if (!(t >= this.lastFrameT && t <= MAX_TIME_S)) {
      throw new RangeError(`frame time ${t} s is outside [${this.lastFrameT}, ${MAX_TIME_S}]`);
    }
    const seq = this.seq;
    this.seq = seqNext(seq);
    if (this.connection.state !== "joined") return undefined;
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
    this.connection.poseRateHz = rateHz;
    if (this.connection.version < PROTOCOL_V2 || this.connection.state !== "joined") return false;
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
    this.connection.forecastMs = ms;
    if (this.connection.version < PROTOCOL_V2 || this.connection.state !== "joined") return false;
    return this.send({ type: "forecast", ms });
  }

  /** v2: ask for a keyframe of every avatar with the next poses. False on v1 or when not connected. */
  resync(): boolean {
    return this.connection.resync();
  }

  /** Send any message as is (backends: `selector`, `kick`). False when not connected. */
  send(msg: Message): boolean {
    return this.connection.send(msg);
  }

  /**
   * Say `bye` and close. The event stream ends (without an error). Resolves once the
   * socket has closed, or after `timeoutS`. Note that the server remembers the token
   * of a session that said `bye`: the same token cannot join again.
   */
  close(reason = "bye"): Promise<void> {
    return this.connection.close(reason);
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

}

function checkForecast(ms: number): void {
  if (!(ms >= 0 && ms <= MAX_FORECAST_MS)) {
    throw new OutOfRangeError(`forecast ${ms} ms: not within 0-${MAX_FORECAST_MS}`, { field: "ms" });
  }
}
