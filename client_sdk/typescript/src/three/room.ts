/**
 * One avatar per player of a room, added and removed on presence (as the Unity SDK's
 * manager does): feed it the client's events, and each frame the poses to show.
 *
 * ```ts
 * const room = new AvatarRoom({ parent: scene, create: async () => humanoidFromVRM(await loadVrm()) });
 * for await (const ev of client) { buffers.feed(ev); room.feed(ev); }          // the event loop
 * room.update(buffers.posesAt(client.clock.displayTime(now)), (p) => client.skeletonOf(p)); // each frame
 * ```
 */

import type { Object3D } from "three";

import type { ClientEvent } from "../events.js";
import { offsetsFromPose } from "../rest.js";
import { type Humanoid, HumanoidAvatar } from "./avatar.js";

/** A pose to show: an `InterpolatedPose` or a `Pose`. */
export interface PoseLike {
  readonly positions: ArrayLike<number>;
  readonly rotations?: ArrayLike<number> | undefined;
}

export interface AvatarRoomOptions {
  /** Where the avatars go: a scene, or a group that places posecast's world in it. */
  readonly parent: Object3D;
  /** A fresh model for a player (each player needs its own: bones are per model). */
  readonly create: (player: string, name: string) => Humanoid | Promise<Humanoid>;
  /** An avatar that left (free its geometries, materials and textures here). */
  readonly dispose?: (avatar: HumanoidAvatar, player: string) => void;
  /** An avatar added to {@link parent} (tint it, label it). */
  readonly added?: (avatar: HumanoidAvatar, player: string, name: string) => void;
  /** A model that could not be made (also kept in {@link AvatarRoom.failures}). */
  readonly failed?: (error: unknown, player: string) => void;
  /** Players never shown (e.g. this headset's own id); the welcome's own id is always left out. */
  readonly exclude?: readonly string[];
}

export class AvatarRoom {
  private readonly options: AvatarRoomOptions;
  private readonly ready = new Map<string, HumanoidAvatar>();
  /** Players whose model is being made, by a token that a leave invalidates. */
  private readonly pending = new Map<string, object>();
  private readonly excluded = new Set<string>();
  /** Players whose model could not be made, with the error (until they join again). */
  readonly failures = new Map<string, unknown>();

  constructor(options: AvatarRoomOptions) {
    this.options = options;
    for (const p of options.exclude ?? []) this.excluded.add(p);
  }

  /** The players' avatars whose models are ready. */
  get avatars(): ReadonlyMap<string, HumanoidAvatar> {
    return this.ready;
  }

  /** Presence and welcomes (other events are ignored): adds and removes avatars. */
  feed(ev: ClientEvent): void {
    if (ev.type === "welcome") {
      this.excluded.add(ev.welcome.player);
      const members = new Set(ev.welcome.members.map((m) => m.player));
      for (const player of [...this.ready.keys(), ...this.pending.keys()]) if (!members.has(player)) this.remove(player);
      for (const m of ev.welcome.members) this.add(m.player, m.name);
    } else if (ev.type === "presence") {
      if (ev.event === "leave") this.remove(ev.player);
      else this.add(ev.player, ev.name);
    }
  }

  /** Makes `player`'s avatar unless it has one (or one on the way). */
  add(player: string, name: string = player): void {
    if (this.excluded.has(player) || this.ready.has(player) || this.pending.has(player)) return;
    const token = {};
    this.failures.delete(player);
    this.pending.set(player, token);
    const made = Promise.resolve().then(() => this.options.create(player, name));
    made.then(
      (humanoid) => {
        if (this.pending.get(player) !== token) return; // left meanwhile
        this.pending.delete(player);
        const avatar = new HumanoidAvatar(humanoid);
        avatar.object.visible = false; // until its first pose
        this.ready.set(player, avatar);
        this.options.parent.add(avatar.object);
        this.options.added?.(avatar, player, name);
      },
      (err: unknown) => {
        if (this.pending.get(player) === token) this.pending.delete(player);
        this.failures.set(player, err);
        this.options.failed?.(err, player);
      },
    );
  }

  /** Removes `player`'s avatar (or forgets the one being made). */
  remove(player: string): void {
    this.pending.delete(player);
    const avatar = this.ready.get(player);
    if (avatar === undefined) return;
    this.ready.delete(player);
    avatar.object.removeFromParent();
    this.options.dispose?.(avatar, player);
  }

  /**
   * Drives every ready avatar from this frame's poses (a player without a pose, or a
   * pose without rotations, is hidden), fitting it first to the player's skeleton when
   * that is new: `skeletonOf(player)` (`PosecastClient.skeletonOf`, protocol v2), else
   * the skeleton read off its first pose. Allocates nothing while no skeleton changes.
   */
  update(poses: ReadonlyMap<string, PoseLike>, skeletonOf?: (player: string) => ArrayLike<number> | undefined): void {
    this.framePoses = poses;
    this.frameSkeletonOf = skeletonOf;
    this.ready.forEach(this.step); // forEach: no iterator, no entry arrays
    this.framePoses = undefined;
    this.frameSkeletonOf = undefined;
  }

  private framePoses: ReadonlyMap<string, PoseLike> | undefined;
  private frameSkeletonOf: ((player: string) => ArrayLike<number> | undefined) | undefined;
  private readonly step = (avatar: HumanoidAvatar, player: string): void => {
    const pose = this.framePoses!.get(player);
    if (pose === undefined) {
      avatar.object.visible = false;
      return;
    }
    const skeleton = this.frameSkeletonOf?.(player);
    if (skeleton !== undefined ? avatar.fittedTo !== skeleton : avatar.fittedTo === undefined) {
      avatar.fit(skeleton ?? offsetsFromPose(pose.positions, pose.rotations));
    }
    avatar.object.visible = avatar.update(pose);
  };

  /** Removes every avatar. */
  clear(): void {
    for (const player of [...this.ready.keys(), ...this.pending.keys()]) this.remove(player);
  }
}
