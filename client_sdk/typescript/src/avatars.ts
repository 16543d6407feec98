/**
 * v2 session state for the avatars a connection receives (pure: messages in, poses out).
 *
 * Who each avatar id is, its bone offsets (from `welcome` members, presence `join` and
 * `skeleton`), and the reference state its next record applies to (closed loop:
 * `records.ts`). A `poses` message comes out as one {@link Pose} per record, with the
 * positions rebuilt by FK, the world rotations and the local ones (the record's items).
 *
 * A record that cannot be applied (a delta before its keyframe, an unknown avatar id, a
 * record cut short: BAD_FIELD, field `data`) ends that message: the poses before it
 * are kept, the rest is skipped, and {@link AvatarTable.poses} says so, so the client
 * sends `resync` (the server answers with a keyframe of every avatar).
 */

import { BadFieldError } from "./errors.js";
import type { Member, Pose, Poses, Presence, SkeletonMessage } from "./messages.js";
import { type AvatarState, decodeRecords, type DecodedRecord, fk, items2world, rootMetres, skeleton2offsets } from "./records.js";

interface Avatar {
  readonly player: string;
  offsets: Float64Array;
}

/** What one `poses` message gave: its poses, and the error that cut it short, if any. */
export interface PosesResult {
  readonly poses: Pose[];
  readonly error?: BadFieldError;
}

export class AvatarTable {
  private readonly avatars = new Map<number, Avatar>();
  private readonly states = new Map<number, AvatarState | null>();
  private readonly avatarIds = new Map<string, number>();

  /** Forget everything and announce the welcome's members (a new connection). */
  reset(members: readonly Member[]): void {
    this.avatars.clear();
    this.states.clear();
    this.avatarIds.clear();
    for (const m of members) {
      if (m.avatarId !== undefined && m.skeleton !== undefined) this.announce(m.player, m.avatarId, m.skeleton);
    }
  }

  /** Presence: a v2 `join` announces an avatar id (with no reference yet); `leave` drops it. */
  presence(msg: Presence): void {
    if (msg.event === "join" && msg.avatarId !== undefined && msg.skeleton !== undefined) {
      this.announce(msg.player, msg.avatarId, msg.skeleton);
    } else if (msg.event === "leave") {
      const avatarId = this.avatarIds.get(msg.player);
      if (avatarId === undefined) return;
      this.avatarIds.delete(msg.player);
      this.avatars.delete(avatarId);
      this.states.delete(avatarId);
    }
  }

  /** A player's calibration changed: rebuild its joints with these offsets from now on. */
  skeleton(msg: SkeletonMessage): void {
    // An avatar id not known yet, or now another player's, is announced by it (as the Python
    // and C# SDKs do); the same player keeps its reference.
    this.announce(msg.player, msg.avatarId, msg.skeleton);
  }

  /** Drop every reference (the next record of each avatar must be a keyframe). */
  dropState(): void {
    for (const avatarId of this.states.keys()) this.states.set(avatarId, null);
  }

  /** The avatar id of `player` on this connection. */
  avatarIdOf(player: string): number | undefined {
    return this.avatarIds.get(player);
  }

  /** The bone offsets of `player`, metres, 19 x 3 (PELVIS zero), as last announced. */
  offsetsOf(player: string): Float64Array | undefined {
    const avatarId = this.avatarIds.get(player);
    return avatarId === undefined ? undefined : this.avatars.get(avatarId)?.offsets;
  }

  get size(): number {
    return this.avatars.size;
  }

  /** The records of `msg`, applied in order, as poses. Never throws on bad data. */
  poses(msg: Poses): PosesResult {
    const records: DecodedRecord[] = [];
    let error: BadFieldError | undefined;
    try {
      decodeRecords(msg.data, this.states, records);
    } catch (err) {
      if (!(err instanceof BadFieldError)) throw err; // a bug, not bad input
      error = err;
    }
    const poses = records.map((rec) => this.pose(rec, msg.t));
    return error === undefined ? { poses } : { poses, error };
  }

  private announce(player: string, avatarId: number, skeleton: Uint8Array): void {
    const old = this.avatarIds.get(player);
    if (old !== undefined && old !== avatarId) {
      this.avatars.delete(old);
      this.states.delete(old);
    }
    const known = this.avatars.get(avatarId);
    // An avatar id passed to another player is no longer the old one's (its leave never
    // arrived): that player's late leave or new avatar id must not drop the new avatar.
    if (known !== undefined && known.player !== player) this.avatarIds.delete(known.player);
    this.avatarIds.set(player, avatarId);
    this.avatars.set(avatarId, { player, offsets: skeleton2offsets(skeleton) });
    // A new avatar on this avatar id waits for a keyframe; the same one announced again
    // keeps its reference (the server's PoseStream.announce keeps it and goes on with deltas).
    if (known === undefined || known.player !== player) this.states.set(avatarId, null);
  }

  private pose(rec: DecodedRecord, t: number): Pose {
    const avatar = this.avatars.get(rec.avatarId)!;
    const world = items2world(rec.state.items);
    return {
      type: "pose",
      player: avatar.player,
      seq: rec.state.seq,
      t,
      positions: fk(world, rootMetres(rec.state), avatar.offsets),
      rotations: world,
      localRotations: Float64Array.from(rec.state.items),
      keyframe: rec.keyframe,
      reachLimited: rec.reachLimited,
    };
  }
}
