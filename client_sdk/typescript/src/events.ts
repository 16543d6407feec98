/**
 * What a client's event stream yields, and the bounded queue behind it.
 *
 * Poses supersede each other, so the queue keeps at most one pose per player: a new
 * pose for a player whose last pose is still unread replaces it in place (latest
 * wins, as in the server's outbox, `docs/broadcast.md`). Everything else (presence,
 * errors, welcome, reconnects) is kept in order, up to a bound past which the oldest
 * is dropped and counted. A consumer that stops reading therefore costs at most
 * "one pose per player plus the bound", never an unbounded backlog.
 */

import type { PosecastError, ProtocolError } from "./errors.js";
import type { Pose, Presence, Welcome } from "./messages.js";

/** A non-fatal `error` from the server (the message was dropped, the session goes on). */
export interface ErrorEvent {
  readonly type: "error";
  readonly error: ProtocolError;
}

/** A `welcome`: after {@link PosecastClient.join}, and again after each resume. */
export interface WelcomeEvent {
  readonly type: "welcome";
  readonly welcome: Welcome;
  /** True when this welcome ends a reconnect (the session was resumed). */
  readonly resumed: boolean;
}

/** The connection was lost; the client waits `delayS`, then tries again. */
export interface ReconnectingEvent {
  readonly type: "reconnecting";
  /** 1 for the first retry after a loss, counting up until one succeeds. */
  readonly attempt: number;
  readonly delayS: number;
  /** Why the previous connection (or attempt) ended. */
  readonly cause: PosecastError;
}

export type ClientEvent = Pose | Presence | ErrorEvent | WelcomeEvent | ReconnectingEvent;

interface Slot {
  ev: ClientEvent;
}

interface Waiter {
  resolve(result: IteratorResult<ClientEvent, undefined>): void;
  reject(error: unknown): void;
}

export class EventQueue {
  /** Non-pose events dropped because the consumer fell more than `max` behind. */
  dropped = 0;
  private readonly items: Slot[] = [];
  private readonly unreadPose = new Map<string, Slot>();
  private readonly waiters: Waiter[] = [];
  private ended = false;
  private failure: { error: unknown } | undefined;

  constructor(private readonly max: number) {}

  push(ev: ClientEvent): void {
    if (this.ended) return;
    const waiter = this.waiters.shift();
    if (waiter !== undefined) {
      waiter.resolve({ value: ev, done: false });
      return;
    }
    if (ev.type === "pose") {
      const unread = this.unreadPose.get(ev.player);
      if (unread !== undefined) {
        unread.ev = ev;
        return;
      }
    }
    // A presence (leave, join) or a welcome orders a player's poses: a later pose must not
    // replace an unread one queued before it, or it would be read before the presence.
    if (ev.type === "presence") this.unreadPose.delete(ev.player);
    else if (ev.type === "welcome") this.unreadPose.clear();
    const slot = { ev };
    this.items.push(slot);
    if (ev.type === "pose") this.unreadPose.set(ev.player, slot);
    if (this.items.length > this.max + this.unreadPose.size) this.dropOldestControl();
  }

  /** Finish the stream: readers get what is queued, then `done` (or `error`, once). */
  end(error?: unknown): void {
    if (this.ended) return;
    this.ended = true;
    if (error !== undefined) this.failure = { error };
    while (this.waiters.length > 0 && this.items.length === 0) this.settle(this.waiters.shift()!);
  }

  next(): Promise<IteratorResult<ClientEvent, undefined>> {
    const slot = this.items.shift();
    if (slot !== undefined) {
      const ev = slot.ev;
      if (ev.type === "pose" && this.unreadPose.get(ev.player) === slot) {
        this.unreadPose.delete(ev.player);
      }
      return Promise.resolve({ value: ev, done: false });
    }
    return new Promise((resolve, reject) => {
      const waiter = { resolve, reject };
      if (this.ended) this.settle(waiter);
      else this.waiters.push(waiter);
    });
  }

  get size(): number {
    return this.items.length;
  }

  private settle(waiter: Waiter): void {
    const failure = this.failure;
    this.failure = undefined; // the error is thrown once; later reads are just done
    if (failure !== undefined) waiter.reject(failure.error);
    else waiter.resolve({ value: undefined, done: true });
  }

  private dropOldestControl(): void {
    const i = this.items.findIndex((s) => s.ev.type !== "pose");
    if (i < 0) return;
    this.items.splice(i, 1);
    this.dropped++;
  }
}
