/**
 * One avatar per player: its colour, its name label and player-list entry, and the
 * three ways it can be drawn (the humanoid model bound by the SDK's `AvatarRoom`, the
 * procedural skinned body, the stick figure), and {@link place}, which draws a pose in
 * the mode the panel asks for.
 */

import { BufferGeometry, Material, MeshLambertMaterial, Quaternion } from "three";

import { NUM_JOINTS } from "../src/messages.js";
import { AvatarRoom, type HumanoidAvatar } from "../src/three/index.js";
import { avatarMaterials, buildAvatarGeometry, SkinnedAvatar, stripeMaterial } from "./avatar.js";
import { type AvatarMode, mode, modelKind } from "./hud.js";
import { loadHumanoid } from "./humanoid.js";
import { $ } from "./page.js";
import { scene } from "./scene.js";
import { StickFigure } from "./sticks.js";

/** Saturated, well-separated hues on a dark background; players take them in join order. */
const PALETTE = ["#ff7a1a", "#1ec8ff", "#b86bff", "#5fe35f", "#ff4f8b", "#ffd23f", "#3d7bff", "#ff3b30"];

const playerList = $<HTMLUListElement>("players");
const labels = $<HTMLDivElement>("labels");

const bodyShape = buildAvatarGeometry(); // one geometry for every player
const stripes = stripeMaterial();

export interface Avatar {
  readonly player: string;
  readonly color: string;
  readonly skinned: SkinnedAvatar;
  readonly sticks: StickFigure;
  readonly label: HTMLDivElement;
  readonly item: HTMLLIElement;
  name: string;
  /** The pose last drawn, and as what (undefined: none yet). */
  shown?: { readonly pose: Drawn; readonly as: AvatarMode };
}

/** What is drawn of a player: a pose sampled from the jitter buffer (or, before the first pong, the newest). */
export interface Drawn {
  readonly positions: Float64Array;
  readonly rotations?: Float64Array;
}

export const avatars = new Map<string, Avatar>();
let colorsUsed = 0;

/**
 * The models, one per player, made and dropped on presence by the SDK's `AvatarRoom`
 * (fed in the event loop, `network.ts`), tinted in the player's colour; their poses and
 * fits come from the frame loop.
 */
export const models = new AvatarRoom({
  parent: scene,
  create: async () => (await loadHumanoid(modelKind)).humanoid,
  added: (model, player, name) => tint(model, avatarFor(player, name).color),
  dispose: (model) =>
    model.object.traverse((o) => {
      if ("geometry" in o && o.geometry instanceof BufferGeometry) o.geometry.dispose();
    }),
});

/** The model's body in the player's colour, its stripes pale (the generated models' two materials). */
function tint(model: HumanoidAvatar, color: string): void {
  const [skin] = avatarMaterials(color, stripes);
  model.object.traverse((o) => {
    if (!("material" in o) || !(o.material instanceof Material)) return;
    o.material = o.material.name === "stripes" ? stripes : skin;
  });
}

/** The avatar of `player` (made on first sight, in the next colour), its name brought up to date. */
export function avatarFor(player: string, name: string): Avatar {
  const existing = avatars.get(player);
  if (existing !== undefined) {
    if (existing.name !== name) rename(existing, name);
    return existing;
  }
  const color = PALETTE[colorsUsed++ % PALETTE.length]!;
  const skinned = new SkinnedAvatar(bodyShape, avatarMaterials(color, stripes));
  const sticks = new StickFigure(new MeshLambertMaterial({ color, emissive: color, emissiveIntensity: 0.25 }));
  skinned.mesh.visible = sticks.visible = false; // until the first pose
  scene.add(skinned.mesh, sticks.bones, sticks.joints);
  const label = document.createElement("div");
  label.className = "label";
  label.hidden = true;
  labels.append(label);
  const item = document.createElement("li");
  item.dataset["player"] = player;
  item.dataset["color"] = color;
  const avatar: Avatar = { player, color, skinned, sticks, label, item, name };
  rename(avatar, name);
  playerList.append(item);
  avatars.set(player, avatar);
  return avatar;
}

function rename(a: Avatar, name: string): void {
  a.name = name;
  a.label.textContent = name;
  const swatch = document.createElement("span");
  swatch.className = "swatch";
  swatch.style.background = a.color;
  const id = document.createElement("span");
  id.className = "id";
  id.textContent = a.player;
  const text = document.createElement("span");
  text.className = "name";
  text.textContent = name;
  a.item.replaceChildren(swatch, text, id);
}

export function removeAvatar(player: string): void {
  const a = avatars.get(player);
  if (a === undefined) return;
  scene.remove(a.skinned.mesh, a.sticks.bones, a.sticks.joints);
  a.label.remove();
  a.item.remove();
  avatars.delete(player);
}

/**
 * Debug hook, for the test that shows the attachment checks can fail: bones turned by a
 * quaternion in their own frame before they are placed (a rotation that disagrees with
 * the positions), by joint index.
 */
export const tampered = new Map<number, Quaternion>();
const tamperedRotations = new Float64Array(4 * NUM_JOINTS);
const turned = new Quaternion();

/** Draw `pose` as `avatar`: as its model, body or stick figure, by the mode and what the pose has. */
export function place(avatar: Avatar, pose: Drawn): void {
  const model = models.avatars.get(avatar.player);
  const asModel = mode === "model" && pose.rotations !== undefined && model?.object.visible === true;
  if (asModel) {
    avatar.skinned.mesh.visible = avatar.sticks.visible = false;
    avatar.shown = { pose, as: "model" };
    return;
  }
  if (model !== undefined) model.object.visible = false;
  const asMesh = (mode === "mesh" || mode === "model") && pose.rotations !== undefined;
  let rotations = pose.rotations;
  if (asMesh && tampered.size > 0) {
    tamperedRotations.set(rotations!);
    for (const [j, q] of tampered) turned.fromArray(tamperedRotations, 4 * j).multiply(q).toArray(tamperedRotations, 4 * j);
    rotations = tamperedRotations;
  }
  if (asMesh) avatar.skinned.place(pose.positions, rotations!);
  else avatar.sticks.place(pose.positions);
  avatar.skinned.mesh.visible = asMesh;
  avatar.sticks.visible = !asMesh;
  avatar.shown = { pose, as: asMesh ? "mesh" : "sticks" };
}
