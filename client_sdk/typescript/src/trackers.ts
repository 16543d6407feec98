/**
 * Tracker input by name, and poses by joint name: the friendly side of the arrays
 * the wire carries.
 */

import { NotNormalisedError, OutOfRangeError } from "./errors.js";
import {
  Joint,
  type JointName,
  MAX_COORD_M,
  NUM_TRACKERS,
  type Pose,
  type Tracker,
  type Trackers,
} from "./messages.js";

/** One tracked point in the posecast world: metres, and a unit quaternion xyzw. */
export interface TrackerPose {
  readonly position: readonly [number, number, number];
  readonly orientation: readonly [number, number, number, number];
}

/**
 * The trackers of one frame by slot name. A slot that is absent (or null) is sent as
 * untracked: its `valid` bit is cleared. `t` is the client time the trackers were
 * sampled, in seconds on the client's clock; absent, the client stamps it on send.
 */
export interface FrameInput {
  readonly head?: TrackerPose | null;
  readonly leftHand?: TrackerPose | null;
  readonly rightHand?: TrackerPose | null;
  readonly waist?: TrackerPose | null;
  readonly t?: number;
}

const SLOT_KEYS = ["head", "leftHand", "rightHand", "waist"] as const;
/** An untracked row on the wire: the origin with the identity rotation. */
export const UNTRACKED: Tracker = [0, 0, 0, 0, 0, 0, 1];
const POSITION = { label: "position", unit: " m" } as const;

/**
 * `FrameInput` -> the wire's 4 trackers in slot order and the `valid` bit mask.
 * Checked like the server checks them, so a bad frame fails here, typed, and is never
 * sent: positions finite and within +-1000 m (OutOfRangeError), orientations finite
 * and not zero (NotNormalisedError); orientations are then normalised.
 */
export function toTrackers(input: FrameInput): { trackers: Trackers; valid: number } {
  let valid = 0;
  const rows = SLOT_KEYS.map((key, i): Tracker => {
    const slot = input[key];
    if (!slot) return UNTRACKED;
    valid |= 1 << i;
    return checkedRow(slot.position, slot.orientation, key, `trackers[${i}]`, POSITION);
  });
  if (rows.length !== NUM_TRACKERS) throw new Error("unreachable: 4 slots");
  return { trackers: rows as unknown as Trackers, valid };
}

/**
 * One wire row from a value (a position, or an IMU's acceleration) and an orientation,
 * checked as the server checks it: the value finite and within +-1000
 * (OutOfRangeError), the orientation finite and not zero (NotNormalisedError), then
 * normalised. `name` (`head`, `left_foot`) and `what` (`position 0,1,0 m`'s words)
 * make the messages, `field` names the row.
 */
export function checkedRow(
  value: readonly [number, number, number],
  orientation: readonly [number, number, number, number],
  name: string,
  field: string,
  what: { readonly label: string; readonly unit: string },
): Tracker {
  const [px, py, pz] = value;
  if (!(Math.abs(px) <= MAX_COORD_M && Math.abs(py) <= MAX_COORD_M && Math.abs(pz) <= MAX_COORD_M)) {
    throw new OutOfRangeError(`${name} ${what.label} ${value}${what.unit}`, { field });
  }
  const [qx, qy, qz, qw] = orientation;
  const n = Math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw);
  if (!(Number.isFinite(n) && n > 1e-6)) {
    throw new NotNormalisedError(`${name} orientation ${orientation}`, { field });
  }
  return [px, py, pz, qx / n, qy / n, qz / n, qw / n];
}

/** World position of `joint` in `pose`, metres. */
export function jointPosition(pose: Pose, joint: JointName): [number, number, number] {
  const i = Joint[joint] * 3;
  const p = pose.positions;
  return [p[i]!, p[i + 1]!, p[i + 2]!];
}

/** World rotation (xyzw) of `joint` in `pose`, or undefined when the pose has none. */
export function jointRotation(
  pose: Pose,
  joint: JointName,
): [number, number, number, number] | undefined {
  const q = pose.rotations;
  if (q === undefined) return undefined;
  const i = Joint[joint] * 4;
  return [q[i]!, q[i + 1]!, q[i + 2]!, q[i + 3]!];
}
