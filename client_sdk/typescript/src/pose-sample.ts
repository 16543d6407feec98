/**
 * What an interpolator shows: {@link InterpolatedPose}, a plain result, and
 * {@link PoseSample}, a caller-owned one that `PoseBuffer.poseAtInto` and
 * `Interpolator.posesAtInto` fill in place (see `interp.ts`).
 */

export type SampleMode = "interpolate" | "extrapolate" | "hold";

/** One player's pose as shown at `t` (the query time minus the delay). */
export interface InterpolatedPose {
  readonly player: string;
  /** Server time shown, seconds. */
  readonly t: number;
  /** `seq` of the received pose at or before `t` (the first one while holding it). */
  readonly seq: number;
  /** World positions, metres, joint order (length 3 * J). */
  readonly positions: Float64Array;
  /** World rotations, unit xyzw (length 4 * J); absent when the poses had none. */
  readonly rotations?: Float64Array;
  readonly mode: SampleMode;
}

/**
 * A caller-owned sample that {@link PoseBuffer.poseAtInto} fills in place: its arrays
 * are reused from frame to frame (reallocated only when the joint count changes), so
 * sampling every player every frame allocates nothing once warm.
 */
export class PoseSample {
  player = "";
  /** Server time shown, seconds. */
  t = 0;
  seq = 0;
  mode: SampleMode = "hold";
  /** World positions, metres (length 3 * J). */
  positions = new Float64Array(0);
  /** World rotations, unit xyzw (length 4 * J); meaningful while `hasRotations`. */
  rotationData = new Float64Array(0);
  hasRotations = false;
  /** @internal the Interpolator frame that last filled it */
  frame = -1;

  /** The rotations, or undefined when the poses had none. */
  get rotations(): Float64Array | undefined {
    return this.hasRotations ? this.rotationData : undefined;
  }

  /** A plain {@link InterpolatedPose} with copies of the arrays. */
  toPose(): InterpolatedPose {
    const base = { player: this.player, t: this.t, seq: this.seq, positions: this.positions.slice(), mode: this.mode };
    return this.hasRotations ? { ...base, rotations: this.rotationData.slice() } : base;
  }

  /** @internal size the arrays for `nPos` position and `nRot` rotation numbers */
  shape(nPos: number, nRot: number): void {
    if (this.positions.length !== nPos) this.positions = new Float64Array(nPos);
    this.hasRotations = nRot > 0;
    if (this.hasRotations && this.rotationData.length !== nRot) this.rotationData = new Float64Array(nRot);
  }

  /** @internal */
  copyFrom(o: PoseSample): void {
    this.shape(o.positions.length, o.hasRotations ? o.rotationData.length : 0);
    this.player = o.player;
    this.t = o.t;
    this.seq = o.seq;
    this.mode = o.mode;
    this.positions.set(o.positions);
    if (o.hasRotations) this.rotationData.set(o.rotationData);
  }
}
