/**
 * The viewer's humanoid models, generated in code (no model file, so nothing to
 * license): the body of `avatar.ts` in other proportions, written out as a real binary
 * glTF (GLB) with a node hierarchy and a skin, then loaded back through three.js's
 * `GLTFLoader` (and three-vrm's `VRMLoaderPlugin` for the VRM), exactly as a model file
 * from disk would be, and bound with `@posecast/client/three`.
 *
 * - `vrm`: a VRM 1.0 (`VRMC_vrm`: meta with its licence, humanoid bone map), bones in
 *   VRM's rest convention (identity rotations), shoulder bones that posecast does not
 *   drive, a longer torso and shorter legs than the reference body.
 * - `gltf`: a plain glTF humanoid with Unity's bone names (the `"unity"` rig), each
 *   bone's frame rolled as exporters such as Blender's do (non-identity rest
 *   rotations), long legs, short arms, wide shoulders, narrow hips.
 */

import { Matrix4, Quaternion, Vector3, type Object3D } from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { VRMLoaderPlugin, type VRM } from "@pixiv/three-vrm";

import { BONES } from "../src/conventions.js";
import { JOINT_NAMES, NUM_JOINTS, PARENTS } from "../src/messages.js";
import { REFERENCE_OFFSETS_M, restPositions } from "../src/rest.js";
import { type Humanoid, humanoidFromGLTF, humanoidFromVRM } from "../src/three/index.js";
import { buildAvatarGeometry } from "./avatar.js";

export const MODELS = ["vrm", "gltf"] as const;
export type ModelKind = (typeof MODELS)[number];

interface Spec {
  readonly name: string;
  /** Scale factors of the reference offsets, by body part. */
  readonly torso: number;
  readonly arms: number;
  readonly legs: number;
  /** Half the shoulder width and the hip width, metres (reference: 0.17, 0.09). */
  readonly shoulderX: number;
  readonly hipX: number;
  readonly names: readonly string[];
  readonly vrm: boolean;
  /** Bone frames rolled away from the world's axes. */
  readonly roll: boolean;
}

const SPECS: Readonly<Record<ModelKind, Spec>> = {
  vrm: { name: "posecast VRM humanoid", torso: 1.1, arms: 1.0, legs: 0.92, shoulderX: 0.16, hipX: 0.09, names: BONES.vrm, vrm: true, roll: false },
  gltf: { name: "posecast glTF humanoid", torso: 0.95, arms: 0.85, legs: 1.15, shoulderX: 0.21, hipX: 0.075, names: BONES.unity, vrm: false, roll: true },
};

const ARM = /ARM|HAND/;
const LEG = /THIGH|SHIN|FOOT|TOE/;

/** The model's bone offsets (19 x 3) from the reference body's, by the spec's factors. */
function offsetsOf(spec: Spec): Float64Array {
  const out = new Float64Array(3 * NUM_JOINTS);
  JOINT_NAMES.forEach((name, j) => {
    const f = ARM.test(name) ? spec.arms : LEG.test(name) ? spec.legs : spec.torso;
    const [x, y, z] = REFERENCE_OFFSETS_M[j]!;
    out.set([x * f, y * f, z * f], 3 * j);
    if (name.endsWith("UPPER_ARM")) out[3 * j] = Math.sign(x) * spec.shoulderX;
    if (name.endsWith("THIGH")) out[3 * j] = Math.sign(x) * spec.hipX;
  });
  return out;
}

/** The rolled frame of bone j (world, bind pose): any fixed turn that is not the identity. */
function rollOf(j: number, spec: Spec): Quaternion {
  if (!spec.roll) return new Quaternion();
  const axis = new Vector3(Math.sin(j), 1, Math.cos(2 * j)).normalize();
  return new Quaternion().setFromAxisAngle(axis, 0.4 + 0.15 * j);
}

/** One humanoid as GLB bytes. */
export function humanoidGLB(kind: ModelKind): ArrayBuffer {
  const spec = SPECS[kind];
  const rest = restPositions(offsetsOf(spec));
  let low = 0;
  for (let j = 0; j < NUM_JOINTS; j++) low = Math.min(low, rest[3 * j + 1]!);
  const lift = -low + 0.03; // the toes' lowest ring is some 2 cm under the toe joint
  const shape = buildAvatarGeometry(rest);
  const geo = shape.geometry;

  // Nodes: 0 the root, 1 the mesh, 2 + j joint j, then the two shoulders (VRM only).
  interface Node { name: string; world: Matrix4; parent: number; children: number[]; mesh?: number; skin?: number }
  const nodes: Node[] = [
    { name: spec.name, world: new Matrix4(), parent: -1, children: [] },
    { name: "Body", world: new Matrix4(), parent: 0, children: [], mesh: 0, skin: 0 },
  ];
  const at = (j: number): Vector3 => new Vector3(rest[3 * j]!, rest[3 * j + 1]! + lift, rest[3 * j + 2]!);
  for (let j = 0; j < NUM_JOINTS; j++) {
    nodes.push({ name: spec.names[j]!, world: new Matrix4().compose(at(j), rollOf(j, spec), new Vector3(1, 1, 1)), parent: j === 0 ? 0 : 2 + PARENTS[j]!, children: [] });
  }
  const chest = JOINT_NAMES.indexOf("CHEST");
  for (const side of spec.vrm ? (["LEFT", "RIGHT"] as const) : []) {
    const arm = JOINT_NAMES.indexOf(`${side}_UPPER_ARM`);
    const place = at(chest).lerp(at(arm), 0.6);
    nodes.push({ name: side === "LEFT" ? "leftShoulder" : "rightShoulder", world: new Matrix4().makeTranslation(place), parent: 2 + chest, children: [] });
    nodes[2 + arm]!.parent = nodes.length - 1;
  }
  nodes.forEach((n, i) => n.parent >= 0 && nodes[n.parent]!.children.push(i));

  // Binary data: each accessor's bytes, 4-byte aligned.
  const chunks: Uint8Array[] = [];
  const views: object[] = [];
  const accessors: object[] = [];
  let offset = 0;
  const addAccessor = (data: Float32Array | Uint16Array, type: string, extra: object = {}): number => {
    const bytes = new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
    views.push({ buffer: 0, byteOffset: offset, byteLength: bytes.length });
    chunks.push(bytes);
    const pad = (4 - (bytes.length % 4)) % 4;
    if (pad > 0) chunks.push(new Uint8Array(pad));
    offset += bytes.length + pad;
    const size = { SCALAR: 1, VEC3: 3, VEC4: 4, MAT4: 16 }[type]!;
    accessors.push({ bufferView: views.length - 1, componentType: data instanceof Float32Array ? 5126 : 5123, count: data.length / size, type, ...extra });
    return accessors.length - 1;
  };
  const position = Float32Array.from(geo.getAttribute("position").array);
  for (let i = 1; i < position.length; i += 3) position[i]! += lift;
  const min = [Infinity, Infinity, Infinity];
  const max = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < position.length; i++) {
    min[i % 3] = Math.min(min[i % 3]!, position[i]!);
    max[i % 3] = Math.max(max[i % 3]!, position[i]!);
  }
  const attributes = {
    POSITION: addAccessor(position, "VEC3", { min, max }),
    NORMAL: addAccessor(Float32Array.from(geo.getAttribute("normal").array), "VEC3"),
    JOINTS_0: addAccessor(Uint16Array.from(geo.getAttribute("skinIndex").array), "VEC4"),
    WEIGHTS_0: addAccessor(Float32Array.from(geo.getAttribute("skinWeight").array), "VEC4"),
  };
  const index = geo.getIndex()!.array;
  const primitives = geo.groups.map((g, k) => ({
    attributes,
    indices: addAccessor(Uint16Array.from(index.slice(g.start, g.start + g.count)), "SCALAR"),
    material: k,
  }));
  const inverseBind = new Float32Array(16 * NUM_JOINTS);
  for (let j = 0; j < NUM_JOINTS; j++) inverseBind.set(nodes[2 + j]!.world.clone().invert().elements, 16 * j);
  const ibm = addAccessor(inverseBind, "MAT4");

  const nodeJson = nodes.map((n) => {
    const local = n.parent >= 0 ? nodes[n.parent]!.world.clone().invert().multiply(n.world) : n.world.clone();
    const [t, q, s] = [new Vector3(), new Quaternion(), new Vector3()];
    local.decompose(t, q, s);
    return {
      name: n.name,
      ...(n.children.length > 0 ? { children: n.children } : {}),
      ...(t.lengthSq() > 0 ? { translation: t.toArray() } : {}),
      ...(Math.abs(q.w) < 1 - 1e-12 ? { rotation: q.toArray() } : {}),
      ...(n.mesh === undefined ? {} : { mesh: n.mesh, skin: n.skin }),
    };
  });
  const humanBones: Record<string, { node: number }> = {};
  nodes.forEach((n, i) => i >= 2 && (humanBones[n.name] = { node: i }));
  const json = {
    asset: { version: "2.0", generator: "posecast viewer/humanoid.ts", copyright: "posecast contributors, Apache-2.0 (generated)" },
    scene: 0,
    scenes: [{ nodes: [0] }],
    nodes: nodeJson,
    meshes: [{ name: "Body", primitives }],
    skins: [{ joints: JOINT_NAMES.map((_, j) => 2 + j), inverseBindMatrices: ibm, skeleton: 2 }],
    materials: [
      { name: "body", pbrMetallicRoughness: { baseColorFactor: [0.8, 0.8, 0.8, 1], metallicFactor: 0, roughnessFactor: 0.8 } },
      { name: "stripes", pbrMetallicRoughness: { baseColorFactor: [0.95, 0.95, 0.95, 1], metallicFactor: 0, roughnessFactor: 0.8 } },
    ],
    accessors,
    bufferViews: views,
    buffers: [{ byteLength: offset }],
    ...(spec.vrm
      ? {
          extensionsUsed: ["VRMC_vrm"],
          extensions: {
            VRMC_vrm: {
              specVersion: "1.0",
              meta: {
                name: spec.name,
                version: "1",
                authors: ["posecast contributors"],
                licenseUrl: "https://vrm.dev/licenses/1.0/",
                avatarPermission: "everyone",
                allowExcessivelyViolentUsage: true,
                allowExcessivelySexualUsage: false,
                commercialUsage: "corporation",
                allowPoliticalOrReligiousUsage: true,
                allowAntisocialOrHateUsage: false,
                creditNotation: "unnecessary",
                allowRedistribution: true,
                modification: "allowModificationRedistribution",
                otherLicenseUrl: "https://www.apache.org/licenses/LICENSE-2.0",
              },
              humanoid: { humanBones },
            },
          },
        }
      : {}),
  };
  return glb(json, chunks, offset);
}

/** A GLB container: the JSON chunk, then the binary chunk. */
function glb(json: object, chunks: readonly Uint8Array[], binLength: number): ArrayBuffer {
  let text = new TextEncoder().encode(JSON.stringify(json));
  const pad = (4 - (text.length % 4)) % 4;
  text = Uint8Array.from([...text, ...new Array<number>(pad).fill(0x20)]);
  const total = 12 + 8 + text.length + 8 + binLength;
  const out = new Uint8Array(total);
  const view = new DataView(out.buffer);
  view.setUint32(0, 0x46546c67, true); // "glTF"
  view.setUint32(4, 2, true);
  view.setUint32(8, total, true);
  view.setUint32(12, text.length, true);
  view.setUint32(16, 0x4e4f534a, true); // "JSON"
  out.set(text, 20);
  let at = 20 + text.length;
  view.setUint32(at, binLength, true);
  view.setUint32(at + 4, 0x004e4942, true); // "BIN\0"
  at += 8;
  for (const c of chunks) {
    out.set(c, at);
    at += c.length;
  }
  return out.buffer;
}

const bytes = new Map<ModelKind, ArrayBuffer>();

/**
 * A fresh model of `kind` (each player needs its own bones), parsed from the GLB as a
 * file would be: the VRM through three-vrm's loader plugin, the glTF as it is.
 */
export async function loadHumanoid(kind: ModelKind): Promise<{ humanoid: Humanoid; root: Object3D }> {
  let glbBytes = bytes.get(kind);
  if (glbBytes === undefined) bytes.set(kind, (glbBytes = humanoidGLB(kind)));
  const loader = new GLTFLoader();
  if (kind === "vrm") loader.register((parser) => new VRMLoaderPlugin(parser));
  const gltf = await loader.parseAsync(glbBytes, "");
  if (kind === "vrm") {
    const vrm = gltf.userData["vrm"] as VRM | undefined;
    if (vrm === undefined) throw new Error("the generated VRM did not load as a VRM");
    return { humanoid: humanoidFromVRM(vrm), root: vrm.scene };
  }
  return { humanoid: humanoidFromGLTF(gltf.scene, "unity"), root: gltf.scene };
}
