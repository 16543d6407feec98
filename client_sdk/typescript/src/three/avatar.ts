/**
 * One humanoid model (a VRM, or a glTF with a humanoid bone map) driven by posecast
 * poses in three.js.
 *
 * The fit ({@link HumanoidAvatar.fit}), once per announced skeleton, in the model's rest
 * pose: (1) it turns each mapped bone (parents first) by the least rotation that points
 * it at its chain child as the player's T-pose does, so an A-pose or a model whose
 * bones lean a little becomes the player's T-pose; (2) it scales each mapped bone
 * uniformly (its children compensate, so scales never compound) so that its length to
 * that child is the player's, and the leaf bones (head, hands, toes) by the ratio of the
 * hips heights: a bone's mesh is scaled, never stretched along one axis, and no bone
 * along a chain is moved; (3) the limbs' roots (upper arms, thighs), where the model's
 * shoulders or hips are wider or narrower than the player's, are set at the player's
 * offsets from their parent joint. The result: in the player's T-pose every mapped
 * bone sits at the player's rest joint, so the pose's world rotations put it where the
 * player's FK does.
 *
 * Each frame ({@link HumanoidAvatar.update}): a mapped bone's world rotation is the
 * pose's world rotation of its joint times the bone's fitted T-pose world rotation
 * (`docs/game-engines.md`: an engine bone with T-pose rotation `rest` takes `q * rest`),
 * its local rotation what that leaves after its parent; the hips go to the pelvis.
 * Bones without a posecast joint (shoulders, upper chest, fingers) keep their rest.
 * Nothing is allocated per frame.
 *
 * Frames: posecast's world, three.js's and glTF's coincide (+Y up, metres, a character
 * facing +Z): poses are read in the frame of {@link HumanoidAvatar.object}, which a scene
 * places (identity: posecast's world is the scene's). A VRM 0.x model faces -Z: turn it
 * with three-vrm's `VRMUtils.rotateVRM0(vrm)` before binding it.
 */

import { type Object3D, Group, Matrix4, Quaternion, Vector3 } from "three";

import { BONES, type BoneRig } from "../conventions.js";
import { JOINT_NAMES, type JointName, NUM_JOINTS } from "../messages.js";
import { hipsHeight, REFERENCE_OFFSETS_FLAT_M, restPositions } from "../rest.js";

/** Each joint's chain child, whose direction and distance fit the joint's bone (-1: a leaf). */
const CHAIN_CHILD: readonly number[] = (() => {
  const next: Partial<Record<JointName, JointName>> = {
    PELVIS: "SPINE",
    SPINE: "CHEST",
    CHEST: "NECK",
    NECK: "HEAD",
    LEFT_UPPER_ARM: "LEFT_FOREARM",
    LEFT_FOREARM: "LEFT_HAND",
    RIGHT_UPPER_ARM: "RIGHT_FOREARM",
    RIGHT_FOREARM: "RIGHT_HAND",
    LEFT_THIGH: "LEFT_SHIN",
    LEFT_SHIN: "LEFT_FOOT",
    LEFT_FOOT: "LEFT_TOE",
    RIGHT_THIGH: "RIGHT_SHIN",
    RIGHT_SHIN: "RIGHT_FOOT",
    RIGHT_FOOT: "RIGHT_TOE",
  };
  return JOINT_NAMES.map((name) => {
    const c = next[name];
    return c === undefined ? -1 : JOINT_NAMES.indexOf(c);
  });
})();

/** A humanoid model and its bones in posecast joint order (`null`: the model has no such bone). */
export interface Humanoid {
  /** The model's root (a glTF scene, `vrm.scene`), facing +Z, feet on its y = 0. */
  readonly root: Object3D;
  /** 19 entries, joint order; the pelvis, spine, head, arms and legs are required. */
  readonly bones: readonly (Object3D | null)[];
}

/** What {@link humanoidFromVRM} reads of a `VRM` from `@pixiv/three-vrm` (v2 or v3). */
export interface VRMLike {
  readonly scene: Object3D;
  readonly humanoid: {
    autoUpdateHumanBones: boolean;
    getRawBoneNode(name: string): Object3D | null;
  };
}

/**
 * A VRM's humanoid: its raw bones by the VRM names (`BONES.vrm`). Turns off three-vrm's
 * own copying of its normalised rig onto those bones (`autoUpdateHumanBones`), so that
 * `vrm.update(dt)` (spring bones, expressions) leaves the pose alone.
 */
export function humanoidFromVRM(vrm: VRMLike): Humanoid {
  vrm.humanoid.autoUpdateHumanBones = false;
  return { root: vrm.scene, bones: BONES.vrm.map((name) => vrm.humanoid.getRawBoneNode(name)) };
}

/**
 * A glTF humanoid's bones by name: a rig of `BONES` (`"unity"`, `"vrm"`, `"unreal"`,
 * `"unreal_ue4"`) or a map from joint to node name (`{ PELVIS: "mixamorig:Hips", … }`);
 * a joint left out of a map has no bone.
 */
export function humanoidFromGLTF(root: Object3D, map: BoneRig | Readonly<Partial<Record<JointName, string>>>): Humanoid {
  const names = typeof map === "string" ? BONES[map] : JOINT_NAMES.map((j) => map[j]);
  return { root, bones: names.map((name) => (name === undefined ? null : (root.getObjectByName(name) ?? null))) };
}

const REQUIRED: readonly JointName[] = JOINT_NAMES.filter((j) => !["CHEST", "NECK", "LEFT_TOE", "RIGHT_TOE"].includes(j));

interface Rest {
  readonly object: Object3D;
  readonly position: Vector3;
  readonly quaternion: Quaternion;
  readonly scale: Vector3;
}

/** A humanoid model that follows one player's poses. */
export class HumanoidAvatar {
  /** Add this to the scene: the model inside it, in the poses' frame. */
  readonly object: Group = new Group();
  readonly humanoid: Humanoid;
  /** The offsets the model was last fitted to (19 x 3), or undefined before {@link fit}. */
  fittedTo: ArrayLike<number> | undefined;
  private readonly bones: readonly (Object3D | null)[];
  /** Per joint: the nearest mapped ancestor's joint in the model's hierarchy (-1: none). */
  private readonly anchor: Int8Array = new Int8Array(NUM_JOINTS).fill(-1);
  /** Per joint: the bone's fitted T-pose world rotation (in {@link object}'s frame). */
  private readonly tpose: Quaternion[] = JOINT_NAMES.map(() => new Quaternion());
  /** Per joint: the turn from the anchor's world rotation to the bone's parent's (fixed bones between). */
  private readonly between: Quaternion[] = JOINT_NAMES.map(() => new Quaternion());
  /** Per joint, this frame: the bone's world rotation. */
  private readonly world: Quaternion[] = JOINT_NAMES.map(() => new Quaternion());
  /** From the hips' parent to {@link object}'s frame, inverted: where to put the hips. */
  private readonly hipsParentInverse = new Matrix4();
  private readonly rest: Rest[] = [];
  private readonly q = new Quaternion();
  private readonly v = new Vector3();

  constructor(humanoid: Humanoid) {
    if (humanoid.bones.length !== NUM_JOINTS) throw new RangeError("a humanoid has 19 bone entries, joint order");
    const missing = REQUIRED.filter((j) => humanoid.bones[JOINT_NAMES.indexOf(j)] === null);
    if (missing.length > 0) throw new RangeError(`the humanoid has no bone for ${missing.join(", ")}`);
    this.humanoid = humanoid;
    this.bones = humanoid.bones;
    this.object.name = "posecast-avatar";
    this.object.add(humanoid.root);
    humanoid.root.traverse((o) => {
      // A skinned mesh's bounds are three.js's of its pose when first culled: a player who
      // walks away from there would vanish. Avatars are never culled.
      if ((o as { isSkinnedMesh?: boolean }).isSkinnedMesh === true) o.frustumCulled = false;
      this.rest.push({ object: o, position: o.position.clone(), quaternion: o.quaternion.clone(), scale: o.scale.clone() });
    });
    const joint = new Map<Object3D, number>();
    this.bones.forEach((b, j) => b !== null && joint.set(b, j));
    for (let j = 0; j < NUM_JOINTS; j++) {
      for (let o = this.bones[j]?.parent ?? null; o !== null && o !== this.object; o = o.parent) {
        const a = joint.get(o);
        if (a !== undefined) {
          if (a > j) throw new RangeError(`${JOINT_NAMES[j]}'s bone hangs below ${JOINT_NAMES[a]}'s`);
          this.anchor[j] = a;
          break;
        }
      }
    }
    if (this.anchor[0] !== -1) throw new RangeError("the pelvis bone hangs below another joint's bone");
    this.fit(REFERENCE_OFFSETS_FLAT_M);
    this.fittedTo = undefined;
  }

  /** The bone that joint `j` drives (null: the model has none). */
  bone(j: number): Object3D | null {
    return this.bones[j] ?? null;
  }

  /**
   * Fits the model to a player's skeleton: `offsets`, each joint's rest offset from its
   * parent, metres, 19 x 3 (`PosecastClient.skeletonOf`, or `offsetsFromPose`). Allocates;
   * call it when the skeleton changes, not every frame.
   */
  fit(offsets: ArrayLike<number>): void {
    if (offsets.length !== 3 * NUM_JOINTS) throw new RangeError("fit wants 19 x 3 offsets");
    for (const r of this.rest) {
      r.object.position.copy(r.position);
      r.object.quaternion.copy(r.quaternion);
      r.object.scale.copy(r.scale);
    }
    this.object.updateMatrixWorld(true);
    const toObject = this.object.matrixWorld.clone().invert();
    const objectTurn = new Quaternion().setFromRotationMatrix(toObject);
    const at = (o: Object3D): Vector3 => o.getWorldPosition(new Vector3()).applyMatrix4(toObject);
    const turnOf = (o: Object3D): Quaternion => objectTurn.clone().multiply(o.getWorldQuaternion(new Quaternion()));
    const target = restPositions(offsets);
    const want = (from: number, to: number): Vector3 =>
      new Vector3(
        target[3 * to]! - target[3 * from]!,
        target[3 * to + 1]! - target[3 * from + 1]!,
        target[3 * to + 2]! - target[3 * from + 2]!,
      );
    /** The chain child of j that has a bone: the chain skips joints without one. */
    const chainChild = (j: number): number => {
      let c = CHAIN_CHILD[j]!;
      while (c >= 0 && this.bones[c] === null) c = CHAIN_CHILD[c]!;
      return c;
    };

    // (1) The player's T-pose: each bone turned to point at its chain child as the player's does.
    const ratio = JOINT_NAMES.map(() => 1);
    let lowest = Infinity; // the lowest bone (a toe, or an ankle), as hipsHeight measures the player
    for (const b of this.bones) if (b !== null) lowest = Math.min(lowest, at(b).y);
    for (let j = 0; j < NUM_JOINTS; j++) {
      const bone = this.bones[j];
      const c = chainChild(j);
      if (bone == null || c < 0) continue;
      const have = at(this.bones[c]!).sub(at(bone));
      const need = want(j, c);
      if (have.length() < 1e-6 || need.length() < 1e-6) continue;
      ratio[j] = need.length() / have.length();
      const turn = new Quaternion().setFromUnitVectors(have.normalize(), need.normalize());
      const parentTurn = bone.parent === null ? new Quaternion() : turnOf(bone.parent);
      // world' = turn * world; local' = parent^-1 * world'
      bone.quaternion.copy(parentTurn.invert().multiply(turn.multiply(turnOf(bone))));
      bone.updateMatrixWorld(true);
    }
    // The leaves, and the model's size where no chain says: the hips heights' ratio.
    const hips = at(this.bones[0]!).y - lowest;
    const overall = hips > 1e-3 ? hipsHeight(offsets) / hips : 1;
    for (let j = 0; j < NUM_JOINTS; j++) if (chainChild(j) < 0) ratio[j] = overall;

    // (2) Uniform scales: net ratio[j] on bone j, its children compensating (ratios multiply).
    const inherited = (o: Object3D | null): number => {
      for (; o !== null && o !== this.object; o = o.parent) {
        const j = this.bones.indexOf(o);
        if (j >= 0) return ratio[j]!;
      }
      return 1;
    };
    for (let j = 0; j < NUM_JOINTS; j++) {
      const bone = this.bones[j];
      if (bone != null) bone.scale.multiplyScalar(ratio[j]! / inherited(bone.parent));
    }
    this.object.updateMatrixWorld(true);

    // (3) Limb roots (and any joint off its anchor's chain) at the player's offset from the anchor.
    const toWorld = this.object.matrixWorld;
    for (let j = 1; j < NUM_JOINTS; j++) {
      const bone = this.bones[j];
      const a = this.anchor[j]!;
      if (bone == null || a < 0 || chainChild(a) === j || bone.parent === null) continue;
      const place = at(this.bones[a]!).add(want(a, j)).applyMatrix4(toWorld);
      bone.position.copy(bone.parent.worldToLocal(place));
      bone.updateMatrixWorld(true);
    }

    // The fitted T-pose: each bone's world rotation, and the fixed turns between bones.
    for (let j = 0; j < NUM_JOINTS; j++) {
      const bone = this.bones[j];
      if (bone == null) continue;
      this.tpose[j]!.copy(turnOf(bone));
      const parent = bone.parent === null ? new Quaternion() : turnOf(bone.parent);
      const a = this.anchor[j]!;
      this.between[j]!.copy(a < 0 ? parent : this.tpose[a]!.clone().invert().multiply(parent));
    }
    const hipsParent = this.bones[0]!.parent;
    this.hipsParentInverse.copy(toObject);
    if (hipsParent !== null) this.hipsParentInverse.multiply(hipsParent.matrixWorld);
    this.hipsParentInverse.invert();
    this.fittedTo = offsets;
  }

  /**
   * Drives the bones from one pose (an `InterpolatedPose`, a `Pose`): `positions` 19 x 3
   * (only the pelvis is read) and world `rotations` 19 x 4 xyzw, in {@link object}'s
   * frame. Returns false (and changes nothing) for a pose without rotations. Allocates
   * nothing.
   */
  update(pose: { readonly positions: ArrayLike<number>; readonly rotations?: ArrayLike<number> | undefined }): boolean {
    const r = pose.rotations;
    if (r === undefined || r.length !== 4 * NUM_JOINTS || pose.positions.length !== 3 * NUM_JOINTS) return false;
    for (let j = 0; j < NUM_JOINTS; j++) {
      const bone = this.bones[j];
      if (bone == null) continue;
      const w = this.world[j]!.set(r[4 * j]!, r[4 * j + 1]!, r[4 * j + 2]!, r[4 * j + 3]!).normalize();
      w.multiply(this.tpose[j]!);
      const a = this.anchor[j]!;
      // parent's world = anchor's world * between; local = parent^-1 * world
      this.q.copy(this.between[j]!);
      if (a >= 0) this.q.premultiply(this.world[a]!);
      bone.quaternion.copy(this.q.invert().multiply(w));
    }
    const p = pose.positions;
    this.bones[0]!.position.copy(this.v.set(p[0]!, p[1]!, p[2]!).applyMatrix4(this.hipsParentInverse));
    return true;
  }

  /**
   * Where joint `j`'s bone is now, in {@link object}'s frame (the poses' frame), after
   * `object.updateMatrixWorld(true)` (a render does it); `out` when its bone is missing.
   */
  jointPosition(j: number, out: Vector3): Vector3 {
    const bone = this.bones[j];
    if (bone == null) return out;
    return this.object.worldToLocal(bone.getWorldPosition(out));
  }
}
