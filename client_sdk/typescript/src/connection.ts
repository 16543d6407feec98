/**
 * One client's connection to a server, across reconnects: it dials ({@link dialSocket}),
 * says `hello` and waits for the `welcome`, reads every message the server sends into the
 * room state and the event queue, pings for clock sync, and when the connection is lost
 * reconnects with back-off and says `hello` again. {@link PosecastClient} is its public
 * face: it decides what to send, and reads what this connection keeps.
 *
 * States: `open` (the socket is open) -> `joining` (hello sent) -> `joined` (welcome
 * read) <-> `reconnecting` -> `closed` (a `bye`, a fatal error, or no retry left). Each
 * socket has a generation: events from an older socket are ignored.
 */

import type { PosecastClient } from "./client.js";
import type { ClientState, ConnectOptions, JoinOptions } from "./client-options.js";
import { ClockSync } from "./clock.js";
import { decode, encode } from "./codec.js";
import { checkToken, checkUrl, fetchToken, type TokenSource } from "./dial.js";
import {
  ConnectionClosedError,
  errorFromMessage,
  type PosecastError,
  ProtocolError,
  ServerShutdownError,
} from "./errors.js";
import { clearTimer, globalWebSocket, monotonicS, setTimer, type TimerId } from "./env.js";
import { EventQueue } from "./events.js";
import {
  type Message,
  type Pose,
  PROTOCOL_V1,
  PROTOCOL_V2,
  SUBPROTOCOL,
  SUBPROTOCOL_V2,
  type Welcome,
} from "./messages.js";
import { backoffDelayS, isRetryable, type ReconnectPolicy, reconnectPolicy } from "./reconnect.js";
import { RoomState } from "./room-state.js";
import { dialSocket, bytesOf, type WebSocketClass, type WebSocketLike, WS_OPEN } from "./socket.js";

/** What `hello` says, kept for every rejoin (no `layout`: `hmd3+waist`). */
export interface JoinArgs {
  readonly room: string;
  readonly name: string;
  readonly layout?: string;
  readonly options: JoinOptions;
}

const PING_BURST = 4; // pings right after each welcome, so the clock converges at once
const PING_BURST_GAP_S = 0.05;
const RESYNC_GAP_S = 0.25; // at most one automatic resync this often (the server rate-limits them)

export class ClientConnection {
  /** Clock sync from ping/pong (reset on a resume: it may be a new server process). */
  readonly clock = new ClockSync();
  /** The events for the reader: poses, presence, non-fatal errors, welcomes, reconnects. */
  readonly queue: EventQueue;
  /** What is known of the room: welcome, limits, members, poses, v2 avatars. */
  readonly room = new RoomState();
  /** The client's monotonic clock, seconds. */
  readonly now: () => number;
  /** The server's URL, as {@link checkUrl} gave it (leading and trailing whitespace dropped). */
  readonly url: string;
  /** v2: the pose rate and forecast last set ({@link PosecastClient.setPoseRate}), for each `hello`. */
  poseRateHz: number | undefined;
  forecastMs: number | undefined;
  private readonly WebSocketClass: WebSocketClass;
  private readonly reconnectOptions: ReconnectPolicy | undefined;
  private ws: WebSocketLike | undefined;
  private generation = 0;
  private stateNow: ClientState = "open";
  private joinArgs: JoinArgs | undefined;
  private versionNow: number = PROTOCOL_V2;
  private lastResyncT = -Infinity;
  private pending:
    | { resolve(w: Welcome): void; reject(e: PosecastError): void; timer: TimerId }
    | undefined;
  private fatal: PosecastError | undefined;
  private pingTimer: TimerId | undefined;
  private sleepTimer: { id: TimerId; wake(): void } | undefined;
  private closing = false;
  private closed: Promise<void> | undefined;

  /**
   * @throws ConfigInvalidError a URL the client cannot dial, or no token
   * @throws TypeError no WebSocket class (none given, and no global one)
   */
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
    this.WebSocketClass = ctor as WebSocketClass;
    this.queue = new EventQueue(options.maxQueuedEvents ?? 1024);
    this.now = options.clock ?? monotonicS;
    this.reconnectOptions = reconnectPolicy(options.reconnect);
  }

  get state(): ClientState {
    return this.stateNow;
  }

  /** The protocol this connection speaks: 2, or 1 when the server selected `posecast.v1`. */
  get version(): number {
    return this.versionNow;
  }

  /** Open the first socket. */
  async open(): Promise<void> {
    await this.openSocket();
  }

  /** @throws Error join was called before; ConnectionClosedError the client is closed. */
  assertJoinable(): void {
    if (this.joinArgs !== undefined) throw new Error("join() was already called on this client");
    if (this.stateNow !== "open") throw new ConnectionClosedError("the client is closed");
  }

  /** Say `hello` and wait for the `welcome`; on failure the client closes (see PosecastClient.join). */
  async join(args: JoinArgs): Promise<Welcome> {
    this.assertJoinable();
    this.joinArgs = args;
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

  // --- one socket -----------------------------------------------------------------------------

  private openSocket(): Promise<WebSocketLike> {
    const gen = ++this.generation;
    const offered = this.options.protocol === PROTOCOL_V1 ? [SUBPROTOCOL] : [SUBPROTOCOL_V2, SUBPROTOCOL];
    const { ws, open } = dialSocket(this.WebSocketClass, this.url, offered, this.options.timeoutS ?? 10, {
      opened: (protocol) => {
        this.versionNow = protocol === SUBPROTOCOL_V2 ? PROTOCOL_V2 : PROTOCOL_V1;
      },
      data: (data) => this.onData(gen, data),
      closed: (code, reason) => this.onClose(gen, code, reason),
    });
    this.ws = ws;
    this.fatal = undefined;
    return open;
  }

  private async handshake(): Promise<Welcome> {
    const args = this.joinArgs!;
    const token = typeof this.token === "function" ? await fetchToken(this.token) : this.token;
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
    const bytes = bytesOf(data);
    if (bytes === undefined) return; // posecast servers send binary messages only
    let msg: Message;
    try {
      msg = decode(bytes, { limits: this.room.limits, version: this.versionNow });
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
        this.room.welcomed(msg, this.versionNow);
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
        // A record that cannot be applied ends the message, and drops every reference.
        const { poses, error } = this.room.posesOf(msg);
        for (const pose of poses) this.onPose(pose);
        if (error !== undefined) {
          this.queue.push({ type: "error", error });
          if (this.now() - this.lastResyncT >= RESYNC_GAP_S) this.resync();
        }
        return;
      }
      case "skeleton":
        this.room.skeleton(msg);
        return;
      case "presence":
        this.room.presence(msg);
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
    this.room.pose(pose);
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
    this.room.joined(welcome);
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
    return isRetryable(err, typeof this.token === "function");
  }

  private async reconnect(cause: PosecastError): Promise<void> {
    const opts = this.reconnectOptions!;
    this.stateNow = "reconnecting";
    for (let attempt = 1; !this.closing; attempt++) {
      if (attempt > opts.maxAttempts) {
        this.finish(cause);
        return;
      }
      const delayS = backoffDelayS(opts, attempt, this.options.random ?? Math.random);
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
