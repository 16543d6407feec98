/**
 * The stick figure: a cylinder per bone and a ball per joint, drawn from joint positions
 * alone (rotations play no part, so a bone's twist cannot show here; the skinned mesh in
 * `avatar.ts` shows it).
 */

import { CylinderGeometry, InstancedMesh, type Material, Matrix4, Quaternion, SphereGeometry, Vector3 } from "three";

import { Joint, NUM_JOINTS, PARENTS } from "../src/messages.js";

const BONE_RADIUS_M = 0.03;
const JOINT_RADIUS_M = 0.045;
const HEAD_RADIUS_M = 0.11;
const BONES = PARENTS.map((parent, child) => [parent, child] as const).filter(([p]) => p >= 0);

const boneGeometry = new CylinderGeometry(BONE_RADIUS_M, BONE_RADIUS_M, 1, 10, 1); // along +Y
const jointGeometry = new SphereGeometry(1, 14, 10);

const m = new Matrix4();
const q = new Quaternion();
const a3 = new Vector3();
const b3 = new Vector3();
const dir = new Vector3();
const scale = new Vector3();
const UP = new Vector3(0, 1, 0);

export class StickFigure {
  readonly bones: InstancedMesh;
  readonly joints: InstancedMesh;

  constructor(material: Material) {
    this.bones = new InstancedMesh(boneGeometry, material, BONES.length);
    this.joints = new InstancedMesh(jointGeometry, material, NUM_JOINTS);
    this.bones.frustumCulled = this.joints.frustumCulled = false;
  }

  get visible(): boolean {
    return this.bones.visible;
  }

  set visible(on: boolean) {
    this.bones.visible = this.joints.visible = on;
  }

  /** Puts the sticks on the joints (positions 19 x 3, world metres). */
  place(p: ArrayLike<number>): void {
    BONES.forEach(([parent, child], i) => {
      a3.set(p[3 * parent]!, p[3 * parent + 1]!, p[3 * parent + 2]!);
      b3.set(p[3 * child]!, p[3 * child + 1]!, p[3 * child + 2]!);
      dir.subVectors(b3, a3);
      const length = dir.length();
      q.setFromUnitVectors(UP, length > 1e-6 ? dir.divideScalar(length) : UP);
      m.compose(a3.add(b3).multiplyScalar(0.5), q, scale.set(1, Math.max(length, 1e-4), 1));
      this.bones.setMatrixAt(i, m);
    });
    q.identity();
    for (let j = 0; j < NUM_JOINTS; j++) {
      const r = j === Joint.HEAD ? HEAD_RADIUS_M : JOINT_RADIUS_M;
      m.compose(a3.set(p[3 * j]!, p[3 * j + 1]!, p[3 * j + 2]!), q, scale.set(r, r, r));
      this.joints.setMatrixAt(j, m);
    }
    this.bones.instanceMatrix.needsUpdate = true;
    this.joints.instanceMatrix.needsUpdate = true;
  }
}
