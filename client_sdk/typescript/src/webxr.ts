/**
 * WebXR -> posecast frames: {@link fromXRFrame} turns one `XRFrame` into the trackers
 * of one `frame` message.
 *
 * Conventions. A WebXR reference space is right-handed with +Y up, in metres, and
 * the viewer looks down its own -Z axis. The posecast world is also right-handed
 * with +Y up, in metres, so **positions pass through unchanged**. Only the
 * *character forward* convention differs: a posecast tracker orientation is the
 * rotation of a body part whose rest pose faces **+Z** (`proto/README.md`, World
 * frame), while a WebXR pose at identity faces **-Z**. So every orientation is
 * turned 180 degrees about its own Y axis: `q_posecast = q_webxr * (0, 1, 0, 0)`
 * (xyzw), which maps the viewer's forward (-Z) onto posecast forward (+Z) and the
 * viewer's right (+X) onto the character's right (-X); up stays up.
 *
 * What goes where:
 *
 * - HEAD: the viewer pose (`frame.getViewerPose`), the point between the eyes.
 * - LEFT_HAND / RIGHT_HAND: each input source's **grip** pose (`gripSpace`) by
 *   `handedness`. The grip sits in the palm, a few centimetres from the wrist joint
 *   the model was trained on; the 4-point model uses hand positions only, the
 *   headset-only model their orientations too (after a T-pose calibration), and the
 *   grip is what every runtime reports.
 * - WAIST: WebXR has no waist, so the caller supplies one if it has a tracker: an
 *   `XRSpace` (located in `refSpace` each frame) or a pose already in `refSpace`, in
 *   WebXR's -Z-forward convention like every other WebXR pose. Without one, join
 *   with layout `"hmd3"`: the headset-only model predicts the pelvis itself. It reads
 *   the head's and hands' orientations, so send one `calibrate` with a T-pose first
 *   (the server then learns each device's rotation offset, e.g. grip vs. hand).
 *
 * - Other body sites of a tracker set (feet, knees, elbows): the caller's trackers,
 *   given like the waist (`options.sites`); join with the set they make, e.g.
 *   `head,left_hand,right_hand,waist,left_foot,right_foot`. Headset and controllers
 *   alone are the set `head,left_hand,right_hand` (or the layout `hmd3`).
 *
 * A slot the frame cannot locate is left out (its `valid` bit is cleared when the
 * client sends the frame), and so is a controller or body tracker whose pose has
 * `emulatedPosition` set: it lost tracking and its position is only held or guessed
 * (the server then holds its last tracked pose). The head keeps an emulated position
 * (a neck model while the headset lost tracking): it is still the best head there
 * is. Use a **floor-level** reference space (`local-floor` or `bounded-floor`): the
 * model reads Y as height above the floor.
 */

import type { FrameInput, TrackerPose } from "./trackers.js";

/** A `DOMPointReadOnly`. */
export interface XRPointLike {
  readonly x: number;
  readonly y: number;
  readonly z: number;
  readonly w: number;
}

/** An `XRRigidTransform`: a position and an orientation (xyzw), in the reference space. */
export interface XRRigidTransformLike {
  readonly position: XRPointLike;
  readonly orientation: XRPointLike;
}

/** An `XRPose` (or `XRViewerPose`). */
export interface XRPoseLike {
  readonly transform: XRRigidTransformLike;
  /** True when the position is not tracked but held or estimated (tracking lost). */
  readonly emulatedPosition?: boolean;
}

/** An `XRInputSource`: only handedness and the grip space are read. */
export interface XRInputSourceLike {
  readonly handedness: string;
  readonly gripSpace?: object | null | undefined;
}

/** The part of `XRFrame` that {@link fromXRFrame} uses; a real `XRFrame` satisfies it. */
export interface XRFrameLike {
  readonly session: { readonly inputSources: Iterable<XRInputSourceLike> };
  /** Milliseconds on the `performance.now()` timeline, where the browser provides it. */
  readonly predictedDisplayTime?: number;
  getViewerPose(referenceSpace: object): XRPoseLike | null | undefined;
  getPose(space: object, baseSpace: object): XRPoseLike | null | undefined;
}

export interface FromXRFrameOptions {
  /**
   * A tracked waist: an `XRSpace` to locate in `refSpace`, or an `XRRigidTransform`-like
   * pose already in `refSpace` (WebXR convention, -Z forward). Absent: no waist slot.
   */
  readonly waist?: object | XRRigidTransformLike | null;
  /**
   * Further positional trackers of a tracker set (`sites.ts`), each given like
   * `waist`: feet, knees, elbows (and the waist) by camelCase site name. Send the
   * result with a client that joined with the matching set.
   */
  readonly sites?: { readonly [K in BodySiteKey]?: object | XRRigidTransformLike | null };
}

/** The sites WebXR does not locate itself: a tracker set's body trackers. */
export type BodySiteKey =
  | "waist"
  | "leftFoot"
  | "rightFoot"
  | "leftKnee"
  | "rightKnee"
  | "leftElbow"
  | "rightElbow";

/** What {@link fromXRFrame} returns: the four slots' {@link FrameInput}, and any body
 * site it was given (a {@link SitesInput} too). */
export type XRFrameInput = FrameInput & { readonly [K in BodySiteKey]?: TrackerPose };

/**
 * The posecast trackers of one WebXR frame (see the module comment for conventions).
 *
 * `t` is the frame's `predictedDisplayTime` in seconds when the browser gives one
 * (the `performance.now()` timeline, which is also the client's default clock), so
 * `client.sendFrame(fromXRFrame(frame, refSpace))` stamps the frame with the moment
 * its poses are for.
 */
export function fromXRFrame(
  frame: XRFrameLike,
  refSpace: object,
  options: FromXRFrameOptions = {},
): XRFrameInput {
  const out: { -readonly [K in keyof XRFrameInput]: XRFrameInput[K] } = {};
  const viewer = frame.getViewerPose(refSpace);
  if (viewer) out.head = xrToPosecast(viewer.transform);
  for (const source of frame.session.inputSources) {
    if (!source.gripSpace || (source.handedness !== "left" && source.handedness !== "right")) {
      continue;
    }
    const grip = frame.getPose(source.gripSpace, refSpace);
    if (!grip || grip.emulatedPosition === true) continue; // lost: untracked, not frozen
    if (source.handedness === "left") out.leftHand = xrToPosecast(grip.transform);
    else out.rightHand = xrToPosecast(grip.transform);
  }
  const body: [BodySiteKey, object | XRRigidTransformLike | null | undefined][] = [
    ["waist", options.waist],
    ...(Object.entries(options.sites ?? {}) as [BodySiteKey, object | null][]),
  ];
  for (const [key, space] of body) {
    if (!space) continue;
    if (isTransform(space)) out[key] = xrToPosecast(space);
    else {
      const pose = frame.getPose(space, refSpace);
      if (pose && pose.emulatedPosition !== true) out[key] = xrToPosecast(pose.transform);
    }
  }
  if (typeof frame.predictedDisplayTime === "number") out.t = frame.predictedDisplayTime / 1000;
  return out;
}

/**
 * One WebXR pose as a posecast tracker: the position unchanged, the orientation
 * turned 180 degrees about its local Y (`q * (0, 1, 0, 0)`, i.e.
 * `(x, y, z, w) -> (-z, w, x, -y)`), from -Z forward to +Z forward.
 */
export function xrToPosecast(transform: XRRigidTransformLike): TrackerPose {
  const p = transform.position;
  const { x, y, z, w } = transform.orientation;
  return { position: [p.x, p.y, p.z], orientation: [-z, w, x, -y] };
}

function isTransform(v: object): v is XRRigidTransformLike {
  return "position" in v && "orientation" in v;
}
