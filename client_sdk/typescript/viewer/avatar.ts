/**
 * A humanoid skinned mesh built in code, driven by {@link BoneTransforms}.
 *
 * The body is 23 pieces, each a tapered tube of elliptical section with rounded ends,
 * laid out in the reference body's T-pose (`bones.ts`, the bind pose) and merged into
 * one geometry with one bone per joint. A piece starts at its bone's joint and runs to
 * a child joint (or, on the leaf bones head, hands and toes, to a fixed tip). Its
 * vertices follow that bone, and near each end they blend smoothly into the
 * neighbouring bone (the parent at the start, the child at the end), half and half
 * exactly at the joint, so elbows and knees bend without tearing.
 *
 * Twist shows: sections are not round (forearms are wider than deep, hands are flat,
 * feet and the head are not symmetric about their axes), and pale stripes mark the back
 * of each forearm, the front of each shin and the face. A bone's world rotation about
 * its own axis turns its stripe, which a stick figure drawn from positions can never
 * show.
 *
 * Bones are a flat list of children of the mesh (no hierarchy): each is placed
 * directly by its world transform, so the mesh needs nothing but `poseToBones`.
 */

import {
  Bone,
  BufferGeometry,
  Float32BufferAttribute,
  type Material,
  Matrix4,
  MeshLambertMaterial,
  Skeleton,
  SkinnedMesh,
  Uint16BufferAttribute,
  Vector3,
} from "three";

import { Joint, type JointName, JOINT_NAMES, NUM_JOINTS, PARENTS } from "../src/messages.js";
import { type BoneTransforms, emptyBones, poseToBones, REST_POSITIONS_M } from "./bones.js";

type Vec3 = readonly [number, number, number];
const X: Vec3 = [1, 0, 0];
const Y: Vec3 = [0, 1, 0];
const Z: Vec3 = [0, 0, 1];

/** One piece of the body, in the rest pose (metres, the reference body). */
interface Piece {
  /** The bone that carries the piece; the piece starts at this joint. */
  readonly bone: JointName;
  /** Where it ends: a child joint, or (leaf bones) an offset from the start. */
  readonly to: JointName | Vec3;
  /** Half-widths at the start: along `across`, then along the third axis. */
  readonly r0: readonly [number, number];
  /** Half-widths at the end. */
  readonly r1: readonly [number, number];
  /** A rest-pose direction across the piece: the axis of the first half-width. */
  readonly across: Vec3;
  /** A rest-pose direction across the piece: a pale stripe runs along that side. */
  readonly mark?: Vec3;
}

const LEFT_PIECES: readonly Piece[] = [
  { bone: "CHEST", to: "LEFT_UPPER_ARM", r0: [0.07, 0.06], r1: [0.06, 0.055], across: Z },
  { bone: "LEFT_UPPER_ARM", to: "LEFT_FOREARM", r0: [0.052, 0.05], r1: [0.043, 0.04], across: Z },
  // Palms down in the T-pose: the back of the forearm faces +Y.
  { bone: "LEFT_FOREARM", to: "LEFT_HAND", r0: [0.044, 0.036], r1: [0.034, 0.025], across: Z, mark: Y },
  { bone: "LEFT_HAND", to: [0.17, 0, 0], r0: [0.045, 0.017], r1: [0.04, 0.012], across: Z },
  { bone: "PELVIS", to: "LEFT_THIGH", r0: [0.1, 0.1], r1: [0.095, 0.09], across: X },
  { bone: "LEFT_THIGH", to: "LEFT_SHIN", r0: [0.085, 0.085], r1: [0.058, 0.06], across: X },
  { bone: "LEFT_SHIN", to: "LEFT_FOOT", r0: [0.055, 0.058], r1: [0.038, 0.04], across: X, mark: Z },
  { bone: "LEFT_FOOT", to: "LEFT_TOE", r0: [0.045, 0.035], r1: [0.042, 0.022], across: X },
  { bone: "LEFT_TOE", to: [0, 0, 0.06], r0: [0.042, 0.02], r1: [0.035, 0.016], across: X },
];

const mirrorName = (n: JointName): JointName => n.replace(/^LEFT_/, "RIGHT_") as JointName;
const mirrorVec = (v: Vec3): Vec3 => [-v[0], v[1], v[2]];

/** The whole body: trunk, neck and head, then each side (the right mirrors the left). */
export const PIECES: readonly Piece[] = [
  { bone: "PELVIS", to: "SPINE", r0: [0.15, 0.1], r1: [0.14, 0.095], across: X },
  { bone: "SPINE", to: "CHEST", r0: [0.14, 0.095], r1: [0.16, 0.105], across: X },
  { bone: "CHEST", to: "NECK", r0: [0.16, 0.105], r1: [0.065, 0.06], across: X },
  { bone: "NECK", to: "HEAD", r0: [0.05, 0.05], r1: [0.045, 0.045], across: X },
  // The head joint is at ear height; the top of the head some 15 cm above it.
  { bone: "HEAD", to: [0, 0.07, 0.01], r0: [0.08, 0.095], r1: [0.08, 0.09], across: X, mark: Z },
  ...LEFT_PIECES,
  ...LEFT_PIECES.map((p) => ({
    ...p,
    bone: mirrorName(p.bone),
    to: typeof p.to === "string" ? mirrorName(p.to) : mirrorVec(p.to),
    across: mirrorVec(p.across),
    ...(p.mark === undefined ? {} : { mark: mirrorVec(p.mark) }),
  })),
];

const SIDES = 16; // vertices around each ring
const CAP_RINGS = 4; // rings in each rounded end, its pole included
const RING_SPACING_M = 0.03; // along the straight part
const MARK_HALF_ANGLE = (32 * Math.PI) / 180; // a stripe's half-width, as an angle round the axis
const MARK_SPAN: readonly [number, number] = [0.2, 0.8]; // and its extent, pole (0) to pole (1)

/** A ring of vertices at a known place on a piece, for checking the skinned mesh. */
export interface Ring {
  /** `BONE>TO` (`TO` is `tip` on a leaf). */
  readonly piece: string;
  /** 0 at the piece's start joint, 1 at its end joint, 0.5 halfway. */
  readonly t: number;
  /** Joints whose streamed positions it should lie between: `[from, to]` (`to` -1 on a tip). */
  readonly joints: readonly [number, number];
  readonly first: number;
  readonly count: number;
}

export interface AvatarGeometry {
  /** Positions, normals, skinIndex, skinWeight; group 0 the body, group 1 the stripes. */
  readonly geometry: BufferGeometry;
  /** Rings at each piece's joints and halfway along (the tips' own ends excluded). */
  readonly rings: readonly Ring[];
  /** Vertex indices of each piece's stripe, by piece name (`LEFT_FOREARM>LEFT_HAND`). */
  readonly marks: ReadonlyMap<string, readonly number[]>;
}

const smoothstep = (x: number): number => {
  const c = Math.min(1, Math.max(0, x));
  return c * c * (3 - 2 * c);
};
const dot = (a: Vec3, b: Vec3): number => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a: Vec3, b: Vec3): Vec3 => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const unit = (a: Vec3): Vec3 => {
  const n = Math.hypot(a[0], a[1], a[2]);
  return [a[0] / n, a[1] / n, a[2] / n];
};
/** `v` without its component along unit `d`, normalised. */
const across = (v: Vec3, d: Vec3): Vec3 => {
  const k = dot(v, d);
  return unit([v[0] - k * d[0], v[1] - k * d[1], v[2] - k * d[2]]);
};
const restOf = (j: number): Vec3 => [REST_POSITIONS_M[3 * j]!, REST_POSITIONS_M[3 * j + 1]!, REST_POSITIONS_M[3 * j + 2]!];

/**
 * The merged body geometry in the bind pose: the T-pose of `rest` (joint positions, 19 x
 * 3, pelvis at the origin; the reference body's by default). Other proportions make the
 * generated models of `humanoid.ts`.
 */
export function buildAvatarGeometry(rest: Float64Array = REST_POSITIONS_M): AvatarGeometry {
  const restAt = (j: number): Vec3 => [rest[3 * j]!, rest[3 * j + 1]!, rest[3 * j + 2]!];
  const pos: number[] = [];
  const nrm: number[] = [];
  const skinIndex: number[] = [];
  const skinWeight: number[] = [];
  const body: number[] = [];
  const stripe: number[] = [];
  const rings: Ring[] = [];
  const marks = new Map<string, number[]>();

  for (const piece of PIECES) {
    const bone = Joint[piece.bone];
    const parent = PARENTS[bone]!;
    const to = piece.to;
    const child = typeof to === "string" ? Joint[to] : -1;
    const name = `${piece.bone}>${typeof to === "string" ? to : "tip"}`;
    const a = restAt(bone);
    const b: Vec3 = typeof to === "string" ? restAt(Joint[to]) : [a[0] + to[0], a[1] + to[1], a[2] + to[2]];
    const ab: Vec3 = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
    const length = Math.hypot(...ab);
    const d = unit(ab);
    const e1 = across(piece.across, d);
    const e2 = cross(d, e1); // (e1, e2, d) right-handed: rings run counter-clockwise seen from the end
    const cap0 = (piece.r0[0] + piece.r0[1]) / 2;
    const cap1 = (piece.r1[0] + piece.r1[1]) / 2;
    const blend = Math.min(0.07, Math.max(0.02, 0.3 * length)); // half-width of each blend zone, metres

    // Rings: (axial s from the start joint, radius factor, cap angle phi, radii).
    type RingSpec = { s: number; scale: number; axial: number; r: readonly [number, number]; t?: number };
    const specs: RingSpec[] = [];
    for (let i = 0; i < CAP_RINGS; i++) {
      const phi = (Math.PI / 2) * (i / CAP_RINGS); // 0 at the pole
      specs.push({ s: -cap0 * Math.cos(phi), scale: Math.sin(phi), axial: -Math.cos(phi), r: piece.r0 });
    }
    const steps = 2 * Math.max(1, Math.ceil(length / RING_SPACING_M / 2)); // even: a ring halfway
    for (let k = 0; k <= steps; k++) {
      const f = k / steps;
      const r: [number, number] = [
        piece.r0[0] + f * (piece.r1[0] - piece.r0[0]),
        piece.r0[1] + f * (piece.r1[1] - piece.r0[1]),
      ];
      const t = k === 0 ? 0 : k === steps ? 1 : 2 * k === steps ? 0.5 : undefined;
      specs.push({ s: f * length, scale: 1, axial: 0, r, ...(t === undefined ? {} : { t }) });
    }
    for (let i = CAP_RINGS - 1; i >= 0; i--) {
      const phi = (Math.PI / 2) * (i / CAP_RINGS);
      specs.push({ s: length + cap1 * Math.cos(phi), scale: Math.sin(phi), axial: Math.cos(phi), r: piece.r1 });
    }
    const total = cap0 + length + cap1;

    const first = pos.length / 3;
    for (const spec of specs) {
      // Blend weights: toward the parent bone around the start joint, toward the child
      // around the end joint; 0.5 exactly at each joint.
      const toParent = parent >= 0 ? 1 - smoothstep((spec.s + blend) / (2 * blend)) : 0;
      const toChild = child >= 0 ? smoothstep((spec.s - length + blend) / (2 * blend)) : 0;
      const other = toParent > 0 ? parent : toChild > 0 ? child : bone;
      const w = toParent > 0 ? toParent : toChild;
      if (spec.t !== undefined && (child >= 0 || spec.t === 0)) {
        rings.push({ piece: name, t: spec.t, joints: [bone, child], first: pos.length / 3, count: SIDES });
      }
      for (let m = 0; m < SIDES; m++) {
        const th = (2 * Math.PI * m) / SIDES;
        const [c, s] = [Math.cos(th), Math.sin(th)];
        const [rx, ry] = spec.r;
        const radial = unit([
          (c / rx) * e1[0] + (s / ry) * e2[0],
          (c / rx) * e1[1] + (s / ry) * e2[1],
          (c / rx) * e1[2] + (s / ry) * e2[2],
        ]);
        const lateral = Math.sqrt(Math.max(0, 1 - spec.axial * spec.axial));
        const n = unit([
          radial[0] * lateral + d[0] * spec.axial,
          radial[1] * lateral + d[1] * spec.axial,
          radial[2] * lateral + d[2] * spec.axial,
        ]);
        for (let k = 0; k < 3; k++) {
          pos.push(a[k]! + spec.s * d[k]! + spec.scale * (c * rx * e1[k]! + s * ry * e2[k]!));
        }
        nrm.push(...n);
        skinIndex.push(bone, other, 0, 0);
        skinWeight.push(1 - w, w, 0, 0);
      }
    }

    const mark = piece.mark === undefined ? undefined : across(piece.mark, d);
    const marked = new Set<number>();
    for (let i = 0; i + 1 < specs.length; i++) {
      const u = ((specs[i]!.s + specs[i + 1]!.s) / 2 + cap0) / total; // 0 to 1, pole to pole
      for (let m = 0; m < SIDES; m++) {
        const m1 = (m + 1) % SIDES;
        const v00 = first + i * SIDES + m;
        const v01 = first + i * SIDES + m1;
        const v10 = v00 + SIDES;
        const v11 = v01 + SIDES;
        const th = (2 * Math.PI * (m + 0.5)) / SIDES;
        const side: Vec3 = [
          Math.cos(th) * e1[0] + Math.sin(th) * e2[0],
          Math.cos(th) * e1[1] + Math.sin(th) * e2[1],
          Math.cos(th) * e1[2] + Math.sin(th) * e2[2],
        ];
        const onMark =
          mark !== undefined && u >= MARK_SPAN[0] && u <= MARK_SPAN[1] && dot(side, mark) > Math.cos(MARK_HALF_ANGLE);
        (onMark ? stripe : body).push(v00, v01, v10, v01, v11, v10); // outward faces
        if (onMark) for (const v of [v00, v01, v10, v11]) marked.add(v);
      }
    }
    if (mark !== undefined) marks.set(name, [...marked].sort((x, y) => x - y));
  }

  const geometry = new BufferGeometry();
  geometry.setAttribute("position", new Float32BufferAttribute(pos, 3));
  geometry.setAttribute("normal", new Float32BufferAttribute(nrm, 3));
  geometry.setAttribute("skinIndex", new Uint16BufferAttribute(skinIndex, 4));
  geometry.setAttribute("skinWeight", new Float32BufferAttribute(skinWeight, 4));
  geometry.setIndex([...body, ...stripe]);
  geometry.addGroup(0, body.length, 0);
  geometry.addGroup(body.length, stripe.length, 1);
  return { geometry, rings, marks };
}

/** How far the skinned mesh's rings lie from where the pose's joints say they should. */
export interface Attachment {
  /** Largest distance of a ring's centre from its place between the streamed joints, metres. */
  readonly max_m: number;
  readonly mean_m: number;
  /** The ring with the largest distance: `piece@t`. */
  readonly worst: string;
  /** Largest distance of a bone's origin from its streamed joint, metres. */
  readonly bone_max_m: number;
}

/** One player's skinned body: a `SkinnedMesh` with 19 bones, placed from poses. */
export class SkinnedAvatar {
  readonly mesh: SkinnedMesh;
  readonly bones: readonly Bone[];
  private readonly shape: AvatarGeometry;
  private readonly transforms: BoneTransforms = emptyBones();
  private readonly v = new Vector3();
  private readonly sum = new Vector3();

  /** `materials`: the body's, then the stripes'. */
  constructor(shape: AvatarGeometry, materials: readonly [Material, Material]) {
    this.shape = shape;
    this.mesh = new SkinnedMesh(shape.geometry, [...materials]);
    this.mesh.frustumCulled = false; // its bounding sphere is the bind pose's, not the pose's
    const bones = JOINT_NAMES.map((name) => {
      const bone = new Bone();
      bone.name = name;
      return bone;
    });
    this.bones = bones;
    this.mesh.add(...bones);
    const inverses = bones.map((_, j) => new Matrix4().makeTranslation(...restOf(j)).invert());
    this.mesh.bind(new Skeleton(bones, inverses), new Matrix4());
  }

  /** The bone transforms last placed (see {@link poseToBones}). */
  get current(): BoneTransforms {
    return this.transforms;
  }

  /** Puts every bone where the pose says (positions 19 x 3, world rotations 19 x 4). */
  place(positions: ArrayLike<number>, worldRotations: ArrayLike<number>): void {
    const t = poseToBones(positions, worldRotations, this.transforms);
    for (let j = 0; j < NUM_JOINTS; j++) {
      const bone = this.bones[j]!;
      bone.position.fromArray(t.positions, 3 * j);
      bone.quaternion.fromArray(t.rotations, 4 * j);
      bone.scale.setScalar(t.scale);
    }
  }

  /** The skinned position of vertex `index` (CPU skinning, the shader's formula), world metres. */
  skinnedVertex(index: number, out: Vector3 = new Vector3()): Vector3 {
    this.mesh.getVertexPosition(index, out);
    return out.applyMatrix4(this.mesh.matrixWorld);
  }

  /** The mean skinned position of some vertices, world metres. */
  skinnedCentroid(indices: Iterable<number>, out: Vector3 = new Vector3()): Vector3 {
    this.mesh.updateMatrixWorld(true);
    out.set(0, 0, 0);
    let n = 0;
    for (const i of indices) {
      out.add(this.skinnedVertex(i, this.v));
      n++;
    }
    return out.multiplyScalar(1 / Math.max(n, 1));
  }

  /** The stripe of piece `name` (`LEFT_FOREARM>LEFT_HAND`), its skinned centre. */
  markCentroid(name: string, out: Vector3 = new Vector3()): Vector3 {
    const mark = this.shape.marks.get(name);
    if (mark === undefined) throw new RangeError(`no stripe on ${name}`);
    return this.skinnedCentroid(mark, out);
  }

  /**
   * Compares the skinned mesh with the joint positions it was placed from: each
   * checked ring's centre (at a piece's joints and halfway between them) against the
   * same point between the streamed joints. A bone whose rotation disagrees with the
   * positions (a limb pointing elsewhere than its joints) moves its rings away.
   */
  attachment(positions: ArrayLike<number>): Attachment {
    this.mesh.updateMatrixWorld(true);
    let max = 0;
    let total = 0;
    let worst = "";
    for (const ring of this.shape.rings) {
      const [from, to] = ring.joints;
      const idx = Array.from({ length: ring.count }, (_, k) => ring.first + k);
      const c = this.skinnedCentroid(idx, this.sum);
      let err = 0;
      for (let k = 0; k < 3; k++) {
        const p0 = positions[3 * from + k]!;
        const p1 = to >= 0 ? positions[3 * to + k]! : p0;
        const want = p0 + ring.t * (p1 - p0);
        err += (c.getComponent(k) - want) ** 2;
      }
      err = Math.sqrt(err);
      total += err;
      if (err > max) [max, worst] = [err, `${ring.piece}@${ring.t}`];
    }
    let boneMax = 0;
    for (let j = 0; j < NUM_JOINTS; j++) {
      this.v.setFromMatrixPosition(this.bones[j]!.matrixWorld);
      const e = Math.hypot(this.v.x - positions[3 * j]!, this.v.y - positions[3 * j + 1]!, this.v.z - positions[3 * j + 2]!);
      boneMax = Math.max(boneMax, e);
    }
    return { max_m: max, mean_m: total / Math.max(1, this.shape.rings.length), worst, bone_max_m: boneMax };
  }
}

/** The body's and the stripes' materials for a player colour (Lambert: cheap on software GL). */
export function avatarMaterials(color: string, stripe: Material): [Material, Material] {
  return [new MeshLambertMaterial({ color, emissive: color, emissiveIntensity: 0.2 }), stripe];
}

/** One stripe material for every player: pale and unsaturated, so it is no player's colour. */
export function stripeMaterial(): Material {
  return new MeshLambertMaterial({ color: "#eeeeee", emissive: "#ffffff", emissiveIntensity: 0.15 });
}
