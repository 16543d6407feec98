/**
 * Debug hook: while `posecastViewer.track` runs, each drawn frame reads the models' bound
 * skeletons back and measures them against the poses that drove them.
 */

import { Vector3 } from "three";

import { Joint } from "../src/messages.js";
import { fk } from "../src/records.js";
import { skeletonOf } from "./network.js";
import { avatars, models } from "./players.js";

/** Per player, over a tracked span: its model's hands and feet against the poses that drove it. */
export interface Track {
  frames: number;
  hands_max_m: number;
  feet_max_m: number;
  /** How far the model's hips and left hand travelled (summed frame to frame), metres. */
  hips_path_m: number;
  hand_path_m: number;
  /** The drawn poses' own disagreement: their hands and feet against FK of their rotations, metres. */
  pose_fk_max_m: number;
  /** Frames by the jitter buffer's sample mode. */
  readonly modes: Record<string, number>;
  readonly last: Vector3[];
}
const ENDS = [Joint.LEFT_HAND, Joint.RIGHT_HAND, Joint.LEFT_FOOT, Joint.RIGHT_FOOT] as const;
const bonePos = new Vector3();

/** Add this frame of every player shown as a model to `into`. */
export function trackModels(into: Map<string, Track>): void {
  for (const a of avatars.values()) {
    const model = models.avatars.get(a.player);
    if (a.shown?.as !== "model" || model === undefined || !model.object.visible) continue;
    const p = a.shown.pose.positions;
    const t = into.get(a.player) ?? { frames: 0, hands_max_m: 0, feet_max_m: 0, hips_path_m: 0, hand_path_m: 0, pose_fk_max_m: 0, modes: {}, last: [] };
    into.set(a.player, t);
    model.object.updateMatrixWorld(true);
    for (const j of ENDS) {
      model.jointPosition(j, bonePos);
      const e = Math.hypot(bonePos.x - p[3 * j]!, bonePos.y - p[3 * j + 1]!, bonePos.z - p[3 * j + 2]!);
      if (j === Joint.LEFT_HAND || j === Joint.RIGHT_HAND) t.hands_max_m = Math.max(t.hands_max_m, e);
      else t.feet_max_m = Math.max(t.feet_max_m, e);
    }
    const hips = model.jointPosition(Joint.PELVIS, new Vector3());
    const hand = model.jointPosition(Joint.LEFT_HAND, new Vector3());
    if (t.last.length === 2) {
      t.hips_path_m += hips.distanceTo(t.last[0]!);
      t.hand_path_m += hand.distanceTo(t.last[1]!);
    }
    t.last.splice(0, 2, hips, hand);
    const skeleton = skeletonOf(a.player);
    const r = a.shown.pose.rotations;
    if (skeleton !== undefined && r !== undefined) {
      const q = fk(r, p, skeleton);
      for (const j of ENDS) t.pose_fk_max_m = Math.max(t.pose_fk_max_m, Math.hypot(q[3 * j]! - p[3 * j]!, q[3 * j + 1]! - p[3 * j + 1]!, q[3 * j + 2]! - p[3 * j + 2]!));
    }
    const mode = (a.shown.pose as { mode?: string }).mode ?? "newest";
    t.modes[mode] = (t.modes[mode] ?? 0) + 1;
    t.frames++;
  }
}
