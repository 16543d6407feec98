/**
 * What a client knows of its room (pure: messages in, state out; no sockets, no timers):
 * the latest `welcome` and its limits, the members kept up to date from presence, the
 * newest pose of each player, and on v2 each avatar's skeleton and reference state
 * ({@link AvatarTable}), from which `poses` messages become pose events.
 *
 * The client feeds it every message it receives and puts the events on its queue; a
 * reconnect starts it over from the new `welcome`, keeping the poses of members still
 * there.
 */

import { AvatarTable, type PosesResult } from "./avatars.js";
import {
  DEFAULT_LIMITS,
  type Limits,
  type Member,
  type Pose,
  type Poses,
  type Presence,
  PROTOCOL_V2,
  type SkeletonMessage,
  type Welcome,
} from "./messages.js";

export class RoomState {
  /** The latest `welcome` (a resume replaces it). */
  welcome: Welcome | undefined;
  /** The limits in force (the v1 defaults until the welcome). */
  limits: Limits = DEFAULT_LIMITS;
  /** The players in the room now, by id. */
  readonly members = new Map<string, Member>();
  /** The newest pose of each player, by id. */
  readonly poses = new Map<string, Pose>();
  private readonly avatars = new AvatarTable();
  private badRecordsNow = 0;

  /** v2: `poses` messages cut short by a record that could not be applied. */
  get badRecords(): number {
    return this.badRecordsNow;
  }

  /**
   * A connection speaking protocol `version` was welcomed: the avatar table starts over
   * from its members (v2). Call it at once, before the next message: poses may follow.
   */
  welcomed(welcome: Welcome, version: number): void {
    this.avatars.reset(version >= PROTOCOL_V2 ? welcome.members : []);
  }

  /**
   * Joined or resumed with `welcome`: its limits and members are in force, and the poses
   * of players no longer in the room are forgotten.
   */
  joined(welcome: Welcome): void {
    this.welcome = welcome;
    this.limits = welcome.limits;
    this.members.clear();
    for (const m of welcome.members) this.members.set(m.player, m);
    for (const player of [...this.poses.keys()]) {
      if (!this.members.has(player)) this.poses.delete(player);
    }
  }

  /** A pose event (v1's `pose`, or one of a v2 `poses` message): the player's newest. */
  pose(pose: Pose): void {
    this.poses.set(pose.player, pose);
  }

  /**
   * v2: the records of a `poses` message as poses (not yet kept: pass each to
   * {@link pose}), and the error that cut it short, if any. After such an error every
   * reference is dropped: the records after the bad one were skipped, so their
   * references are stale, and no delta may apply to one (as the C# SDK does).
   */
  posesOf(msg: Poses): PosesResult {
    const result = this.avatars.poses(msg);
    if (result.error !== undefined) {
      this.badRecordsNow++;
      this.avatars.dropState();
    }
    return result;
  }

  /** v2: a player's avatar announced again, with a new skeleton. */
  skeleton(msg: SkeletonMessage): void {
    this.avatars.skeleton(msg);
  }

  /** A join, leave or stale: the avatar table (v2), and the members where it is this room's. */
  presence(msg: Presence): void {
    this.avatars.presence(msg);
    if (msg.room !== this.welcome?.room) return;
    if (msg.event === "leave") {
      this.members.delete(msg.player);
      this.poses.delete(msg.player);
    } else {
      const known = this.members.get(msg.player);
      this.members.set(
        msg.player,
        msg.avatarId !== undefined && msg.skeleton !== undefined
          ? { player: msg.player, name: msg.name, avatarId: msg.avatarId, skeleton: msg.skeleton }
          : { ...known, player: msg.player, name: msg.name },
      );
    }
  }

  /** v2: the bone offsets of `player`, metres, 19 x 3 (PELVIS zero), as last announced. */
  offsetsOf(player: string): Float64Array | undefined {
    return this.avatars.offsetsOf(player);
  }
}
