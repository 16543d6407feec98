/**
 * The posecast live viewer: joins a room as a spectator with the SDK and draws every
 * player in 3D (three.js) as a humanoid model (a generated VRM or glTF, `humanoid.ts`,
 * bound with the SDK's three.js binding `src/three`, `?model=vrm|gltf`), as the
 * procedural skinned body driven by the streamed joint rotations (`avatar.ts`), or as a
 * stick figure from the joint positions (`sticks.ts`; the button in the panel cycles
 * them, the `s` key switches to sticks and back, `?avatar=model|mesh|sticks`), with name labels,
 * a player list and a room picker. It speaks protocol v2 (the SDK's default: poses
 * rebuilt by FK from rotation records, about 53 bytes a pose) and falls back to v1 on a
 * server that only has v1; the status line names the version. `scripts/build-viewer.mjs` bundles it into the one file the server
 * serves at `/viewer/viewer.js` (`server/posecast/online/shell/http.py`).
 *
 * Token: `#token=` (preferred: a fragment never reaches the server or its logs) or
 * `?token=` in the page URL; it is removed from the address bar once read. Without
 * one, the page asks the server's dev-only `token` endpoint (`posecast serve --dev`,
 * loopback clients only) for a short-lived spectator token for the room, again on
 * every reconnect.
 */

import {
  AmbientLight,
  BufferGeometry,
  Color,
  Material,
  DirectionalLight,
  Float32BufferAttribute,
  HemisphereLight,
  LineBasicMaterial,
  LineSegments,
  MeshLambertMaterial,
  PerspectiveCamera,
  Quaternion,
  Scene,
  Vector3,
  WebGLRenderer,
} from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

import { connect, Interpolator, type PosecastClient, PosecastError, type TokenSource } from "../src/index.js";
import { Joint, type JointName, NUM_JOINTS } from "../src/messages.js";
import { fk } from "../src/records.js";
import { avatarMaterials, buildAvatarGeometry, PIECES, SkinnedAvatar, stripeMaterial } from "./avatar.js";
import { REFERENCE_OFFSETS_M } from "./bones.js";
import { AvatarRoom, HumanoidAvatar } from "../src/three/index.js";
import { loadHumanoid, type ModelKind } from "./humanoid.js";
import { StickFigure } from "./sticks.js";

/** Saturated, well-separated hues on a dark background; players take them in join order. */
const PALETTE = ["#ff7a1a", "#1ec8ff", "#b86bff", "#5fe35f", "#ff4f8b", "#ffd23f", "#3d7bff", "#ff3b30"];
const LABEL_ABOVE_HEAD_M = 0.28;
/**
 * Debug hook: a pixel of a player's colour farther than this beyond every piece of the
 * player's body (its half-width around the streamed bone) is a stray.
 */
const STRAY_MARGIN_M = 0.04;

const params = new URLSearchParams(location.search);
const fragment = new URLSearchParams(location.hash.slice(1));
const room = params.get("room") || "demo";
const urlToken = fragment.get("token") ?? params.get("token");
if (params.has("token")) {
  // Keep the token out of the address bar, history and bookmarks from here on.
  params.delete("token");
  history.replaceState(null, "", `${location.pathname}?${params}${location.hash}`);
}
/** The page lives at <prefix>/viewer/; the WebSocket at <prefix>/ (or ?ws=). */
const prefix = location.pathname.replace(/viewer\/?$/, "");
const wsUrl = params.get("ws") ?? `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}${prefix}`;

const $ = <T extends HTMLElement>(id: string): T => document.getElementById(id) as T;
const status = $<HTMLDivElement>("status");
const playerList = $<HTMLUListElement>("players");
const labels = $<HTMLDivElement>("labels");
const roomInput = $<HTMLInputElement>("room");
roomInput.value = room;

/**
 * `model`: the humanoid model (the default); `mesh`: the procedural skinned body; (both:
 * poses without rotations fall back to sticks); `sticks`: the stick figure.
 */
type AvatarMode = "model" | "mesh" | "sticks";
const MODES: readonly AvatarMode[] = ["model", "mesh", "sticks"];
let mode: AvatarMode = MODES.find((m) => m === params.get("avatar")) ?? "model";
/** The last mode that was not sticks: the `s` key goes back to it. */
let body: Exclude<AvatarMode, "sticks"> = mode === "sticks" ? "model" : mode;
const modelKind: ModelKind = params.get("model") === "gltf" ? "gltf" : "vrm";
const modeButton = $<HTMLButtonElement>("avatar-mode");
const nextMode = (m: AvatarMode): AvatarMode => MODES[(MODES.indexOf(m) + 1) % MODES.length]!;

function setMode(next: AvatarMode): void {
  mode = next;
  if (next !== "sticks") body = next;
  modeButton.textContent = `show ${nextMode(next) === "mesh" ? "body" : nextMode(next)}`;
  modeButton.setAttribute("aria-pressed", String(next !== "model"));
  const q = new URLSearchParams(location.search);
  if (next === "model") q.delete("avatar");
  else q.set("avatar", next);
  history.replaceState(null, "", `${location.pathname}?${q}${location.hash}`); // a reload keeps it
}
setMode(mode);
modeButton.addEventListener("click", () => setMode(nextMode(mode)));
document.addEventListener("keydown", (ev) => {
  if (ev.key !== "s" || ev.ctrlKey || ev.metaKey || ev.altKey) return;
  if (ev.target instanceof HTMLInputElement) return; // typing a room name
  setMode(mode === "sticks" ? body : "sticks");
});

function setStatus(text: string, error = false): void {
  status.textContent = text;
  status.classList.toggle("error", error);
}

// --- room picker ------------------------------------------------------------------------

$<HTMLFormElement>("room-form").addEventListener("submit", (ev) => {
  ev.preventDefault();
  const next = roomInput.value.trim();
  if (!next || next === room) return;
  const q = new URLSearchParams(location.search);
  q.set("room", next);
  location.search = q.toString(); // a reload: a fresh token for the new room
});

/** Dev servers list their rooms (`rooms`); production servers answer 404. */
async function refreshRooms(): Promise<void> {
  try {
    const res = await fetch("rooms", { cache: "no-store" });
    if (!res.ok) return;
    const rooms = (await res.json()) as { room: string; players: number }[];
    const list = $<HTMLDataListElement>("rooms");
    list.replaceChildren(
      ...rooms.map((r) => {
        const opt = document.createElement("option");
        opt.value = r.room;
        opt.label = `${r.players} player${r.players === 1 ? "" : "s"}`;
        return opt;
      }),
    );
    setTimeout(() => void refreshRooms(), 3000);
  } catch {
    /* no room list: the picker is a plain text field */
  }
}

// --- the token ------------------------------------------------------------------------------

class NoTokenError extends Error {}

const devToken = async (): Promise<string> => {
  const res = await fetch(`token?room=${encodeURIComponent(room)}`, { cache: "no-store" });
  if (!res.ok) throw new NoTokenError(`no dev token (HTTP ${res.status})`);
  return ((await res.json()) as { token: string }).token;
};
const token: TokenSource = urlToken ?? devToken;

function explainToken(): void {
  const help = $<HTMLDivElement>("help");
  help.hidden = false;
  help.innerHTML =
    "This server hands out no viewer tokens (it is not in <code>--dev</code> mode, " +
    "or you are not on its machine). Mint a spectator token for this room, e.g. " +
    "<code>posecast token --role spectator --room ROOM --player viewer-1</code>, " +
    "and open <code>…/viewer/?room=ROOM#token=TOKEN</code>.";
}

// --- three.js scene -------------------------------------------------------------------------

const canvas = $<HTMLCanvasElement>("scene");
const renderer = new WebGLRenderer({ canvas, antialias: true });
renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
const scene = new Scene();
scene.background = new Color("#15171c");
const camera = new PerspectiveCamera(50, 1, 0.05, 200);
camera.position.set(3.2, 2.2, 4.2); // an oblique view: walkers side by side stay apart
const controls = new OrbitControls(camera, canvas);
controls.target.set(0, 1, 0);
controls.enableDamping = true;
scene.add(new HemisphereLight("#ffffff", "#30343c", 1.6));
scene.add(new AmbientLight("#ffffff", 0.5));
const sun = new DirectionalLight("#ffffff", 1.4);
sun.position.set(3, 6, 4);
scene.add(sun);
const grid = floorGrid(30, "#30343d", "#4a4f5a"); // 1 m squares, moved with the players
scene.add(grid);

/**
 * A floor grid of `size` x `size` metres in 1 m squares. Unlike `GridHelper`, every
 * line is cut into 1 m segments: software GL (SwiftShader, e.g. headless Chromium)
 * drops a whole line when one end is behind the camera, and short segments keep that
 * loss to the one square under the camera.
 */
function floorGrid(size: number, color: string, axisColor: string): LineSegments {
  const half = size / 2;
  const points: number[] = [];
  const colors: number[] = [];
  const c = new Color(color);
  const axis = new Color(axisColor);
  for (let k = -half; k <= half; k++) {
    const col = k === 0 ? axis : c;
    for (let s = -half; s < half; s++) {
      points.push(s, 0, k, s + 1, 0, k, k, 0, s, k, 0, s + 1);
      for (let v = 0; v < 4; v++) colors.push(col.r, col.g, col.b);
    }
  }
  const geometry = new BufferGeometry();
  geometry.setAttribute("position", new Float32BufferAttribute(points, 3));
  geometry.setAttribute("color", new Float32BufferAttribute(colors, 3));
  return new LineSegments(geometry, new LineBasicMaterial({ vertexColors: true }));
}

const bodyShape = buildAvatarGeometry(); // one geometry for every player
const stripes = stripeMaterial();

interface Avatar {
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
interface Drawn {
  readonly positions: Float64Array;
  readonly rotations?: Float64Array;
}

const avatars = new Map<string, Avatar>();
let colorsUsed = 0;

/**
 * The models, one per player, made and dropped on presence by the SDK's `AvatarRoom`
 * (fed in the event loop below), tinted in the player's colour; their poses and fits
 * come from the frame loop.
 */
const models = new AvatarRoom({
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

function avatarFor(player: string, name: string): Avatar {
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

function removeAvatar(player: string): void {
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
const tampered = new Map<number, Quaternion>();
const tamperedRotations = new Float64Array(4 * NUM_JOINTS);
const turned = new Quaternion();

function place(avatar: Avatar, pose: Drawn): void {
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

// --- the frame loop -------------------------------------------------------------------------

let client: PosecastClient | undefined;
const skeletonOf = (player: string): Float64Array | undefined => client?.skeletonOf(player);
/** While the benchmark runs (`posecastViewer.bench`), the page draws nothing. */
let benching = false;
/** Every player's jitter buffer: poses arrive at 60 Hz or less, unevenly; frames come at the display's rate. */
const buffers = new Interpolator();
/**
 * Debug switch (`?interp=off`, `posecastViewer.interpolate`): off, each frame draws the
 * newest pose as streamed (the checks compare the models with streamed positions).
 */
let interpolate = params.get("interp") !== "off";
let frames = 0;

/**
 * Each player's pose for this frame: sampled at the server's time now once the clock is
 * synced, on the display clock, which slews the offset estimate's steps (up to tens of
 * ms when the best ping leaves the window) instead of moving every avatar by them.
 */
function posesNow(c: PosecastClient | undefined): ReadonlyMap<string, Drawn> {
  if (c === undefined) return new Map();
  if (c.clock.offsetS === undefined || !interpolate) return c.poses; // displayTime throws until the first pong
  return buffers.posesAt(c.clock.displayTime(performance.now() / 1000));
}
const centroid = new Vector3();
const follow = new Vector3();
const head = new Vector3();

function resize(): void {
  const w = canvas.clientWidth;
  const h = canvas.clientHeight;
  if (canvas.width !== Math.round(w * renderer.getPixelRatio()) || camera.aspect !== w / h) {
    renderer.setSize(w, h, false);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
  }
}

/**
 * Debug hook: freezing draws the newest poses as they were streamed (not the jitter
 * buffer's samples, whose positions and rotations part during an extrapolation) once,
 * then keeps drawing them (and the camera stays), so checks compare the mesh with the
 * streamed joints.
 */
let frozen = false;
let freezing = false;

function draw(): void {
  resize();
  let n = 0;
  centroid.set(0, 0, 0);
  const poses = freezing ? (client?.poses ?? new Map<string, Drawn>()) : frozen ? new Map<string, Drawn>() : posesNow(client);
  if (mode === "model" && (freezing || !frozen) && !benching) {
    models.update(poses, skeletonOf); // fits on a new skeleton, hides a model without a pose
  }
  freezing = false;
  for (const [player, pose] of poses) {
    const avatar = avatarFor(player, client?.members.get(player)?.name ?? player);
    place(avatar, pose);
    centroid.x += pose.positions[0]!;
    centroid.z += pose.positions[2]!;
    n++;
  }
  if (n > 0) {
    // Follow the players: move the orbit target (and the camera with it) toward them.
    centroid.multiplyScalar(1 / n).setY(1.0);
    follow.subVectors(centroid, controls.target).multiplyScalar(0.08);
    controls.target.add(follow);
    camera.position.add(follow);
    grid.position.set(Math.round(controls.target.x), 0, Math.round(controls.target.z));
  }
  controls.update();
  renderer.render(scene, camera);
  const w = canvas.clientWidth;
  const h = canvas.clientHeight;
  for (const avatar of avatars.values()) {
    const pose = frozen ? avatar.shown?.pose : poses.get(avatar.player);
    if (pose === undefined) {
      avatar.label.hidden = true;
      continue;
    }
    const i = 3 * Joint.HEAD;
    head.set(pose.positions[i]!, pose.positions[i + 1]! + LABEL_ABOVE_HEAD_M, pose.positions[i + 2]!);
    head.project(camera);
    avatar.label.hidden = head.z > 1;
    avatar.label.style.left = `${((head.x + 1) / 2) * w}px`;
    avatar.label.style.top = `${((1 - head.y) / 2) * h}px`;
  }
  if (tracking !== undefined) trackModels(tracking);
  frames++;
}

// --- debug hooks for the models: read back from the bound skeletons, and a benchmark ---------

/** Per player, over a tracked span: its model's hands and feet against the poses that drove it. */
interface Track {
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
let tracking: Map<string, Track> | undefined;
const ENDS = [Joint.LEFT_HAND, Joint.RIGHT_HAND, Joint.LEFT_FOOT, Joint.RIGHT_FOOT] as const;
const bonePos = new Vector3();

function trackModels(into: Map<string, Track>): void {
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

/** The benchmark's avatars (not in the scene) and the poses it drives them with. */
let bench: { avatars: HumanoidAvatar[]; poses: Drawn[] } | undefined;

function loop(): void {
  if (!benching) draw();
  requestAnimationFrame(loop);
}

const tipWorld = new Vector3();
const tipRot = new Quaternion();

/**
 * The pieces of the body that avatar `a` shows, as screen segments in CSS pixels `[x0,
 * y0, x1, y1, reach]` between the streamed joints, `reach` being the piece's largest
 * half-width (its ends are as round) plus {@link STRAY_MARGIN_M}, in pixels at the
 * nearer end: every pixel of an attached mesh lies within reach of one of them. The
 * tips of the leaf pieces (head, hands, toes), where no joint is streamed, follow their
 * bones. For sticks: the pieces between joints, with a reach of 15 cm.
 */
function screenBones(a: Avatar): number[][] {
  const shown = a.shown;
  if (shown === undefined) return [];
  const p = shown.pose.positions;
  const w = canvas.clientWidth;
  const h = canvas.clientHeight;
  const focal = h / 2 / Math.tan((camera.fov * Math.PI) / 360); // pixels per metre at 1 m depth
  const toScreen = (v: Vector3): [number, number, number] => {
    const depth = -v.clone().applyMatrix4(camera.matrixWorldInverse).z;
    v.project(camera);
    return [((v.x + 1) / 2) * w, ((1 - v.y) / 2) * h, depth];
  };
  const bones = a.skinned.current;
  const segments: number[][] = [];
  for (const piece of PIECES) {
    const j = Joint[piece.bone];
    const from = new Vector3(p[3 * j]!, p[3 * j + 1]!, p[3 * j + 2]!);
    let to: Vector3;
    if (typeof piece.to === "string") {
      const c = Joint[piece.to];
      to = new Vector3(p[3 * c]!, p[3 * c + 1]!, p[3 * c + 2]!);
    } else if (shown.as === "mesh") {
      tipRot.fromArray(bones.rotations, 4 * j);
      to = tipWorld.set(...piece.to).multiplyScalar(bones.scale).applyQuaternion(tipRot).add(from).clone();
    } else {
      continue;
    }
    const [x0, y0, d0] = toScreen(from);
    const [x1, y1, d1] = toScreen(to);
    const reach = (shown.as === "mesh" ? Math.max(...piece.r0, ...piece.r1) : 0.11) + STRAY_MARGIN_M;
    segments.push([x0, y0, x1, y1, (reach * focal) / Math.max(0.05, Math.min(d0, d1))]);
  }
  return segments;
}

/** For tests and the curious: what the page shows, without parsing pixels or DOM. */
Object.assign(window, {
  posecastViewer: {
    room,
    get frames() {
      return frames;
    },
    get state() {
      return client?.state ?? "connecting";
    },
    get mode() {
      return mode;
    },
    setMode,
    freeze(on: boolean) {
      freezing = on && !frozen;
      frozen = on;
    },
    tamper(joint: JointName, q: [number, number, number, number] | null) {
      if (q === null) tampered.delete(Joint[joint]);
      else tampered.set(Joint[joint], new Quaternion(...q).normalize());
    },
    players: () =>
      [...avatars.values()].map((a) => ({
        player: a.player,
        name: a.name,
        color: a.color,
        drawn: a.skinned.mesh.visible || a.sticks.visible || models.avatars.get(a.player)?.object.visible === true,
        shown: a.shown?.as ?? null,
      })),
    /** Per player: how far the skinned mesh is from the joints it was placed from (`avatar.ts`). */
    skin: () =>
      [...avatars.values()]
        .filter((a) => a.shown?.as === "mesh")
        .map((a) => ({ player: a.player, scale: a.skinned.current.scale, ...a.skinned.attachment(a.shown!.pose.positions) })),
    /** Per player: its bones on the screen (see screenBones). */
    screen: () => [...avatars.values()].map((a) => ({ player: a.player, segments: screenBones(a) })),
    /** The reference body's rest offsets the mesh is built on (tests compare them with the server's). */
    restOffsets: () => REFERENCE_OFFSETS_M.map((o) => [...o]),
    model: modelKind,
    interpolate(on: boolean) {
      interpolate = on;
    },
    /** Per player, over `seconds` of drawn frames: see Track. */
    async track(seconds: number) {
      const into = new Map<string, Track>();
      tracking = into;
      await new Promise((done) => setTimeout(done, seconds * 1000));
      tracking = undefined;
      return [...into].map(([player, { last: _, ...t }]) => ({ player, ...t }));
    },
    /**
     * The benchmark, step 1: `n` models (VRM and glTF in turn), each fitted to a player's
     * skeleton, driven by the players' newest poses; the page stops drawing meanwhile.
     */
    async benchPrepare(n: number) {
      const c = client;
      if (c === undefined || c.poses.size === 0) throw new Error("no poses to drive the benchmark with");
      benching = true;
      const poses = [...c.poses.values()].filter((p) => p.rotations !== undefined);
      const players = [...c.poses.keys()];
      const made: HumanoidAvatar[] = [];
      for (let k = 0; k < n; k++) {
        const avatar = new HumanoidAvatar((await loadHumanoid(k % 2 === 0 ? "vrm" : "gltf")).humanoid);
        const skeleton = c.skeletonOf(players[k % players.length]!);
        if (skeleton !== undefined) avatar.fit(skeleton);
        made.push(avatar);
      }
      bench = { avatars: made, poses };
      return { avatars: made.length, poses: poses.length };
    },
    /**
     * Step 2, one synchronous run (nothing else runs meanwhile): `frames` frames, each
     * driving every avatar from a pose (the players' poses in turn), timed alone and
     * with three.js's matrix update (what a render adds); `allocate` hands each avatar a
     * pose whose rotations getter copies them, an allocation per avatar per frame inside
     * the update path, which the heap check must see.
     */
    benchRun(count: number, allocate: boolean) {
      const b = bench!;
      const nPoses = b.poses.length;
      const copying = b.poses.map((p) => ({
        positions: p.positions,
        get rotations() {
          return p.rotations!.slice();
        },
      }));
      let updateMs = 0;
      let matricesMs = 0;
      for (let f = 0; f < count; f++) {
        const t0 = performance.now();
        for (let k = 0; k < b.avatars.length; k++) {
          b.avatars[k]!.update((allocate ? copying : b.poses)[(k + f) % nPoses]!);
        }
        const t1 = performance.now();
        for (let k = 0; k < b.avatars.length; k++) b.avatars[k]!.object.updateMatrixWorld(true);
        updateMs += t1 - t0;
        matricesMs += performance.now() - t1;
      }
      return { frames: count, avatars: b.avatars.length, update_ms_per_frame: updateMs / count, matrices_ms_per_frame: matricesMs / count };
    },
    benchEnd() {
      bench = undefined;
      benching = false;
    },
  },
});

// --- the connection -------------------------------------------------------------------------

function describeStatus(c: PosecastClient): void {
  const n = c.members.size;
  const rtt = c.clock.rttS;
  setStatus(
    `room ${room} · ${n} player${n === 1 ? "" : "s"} · posecast.v${c.version}` +
      (rtt === undefined ? "" : ` · rtt ${(rtt * 1000).toFixed(0)} ms`),
  );
}

async function run(): Promise<void> {
  setStatus(`connecting to ${wsUrl} …`);
  const c = await connect(wsUrl, token, { reconnect: { maxDelayS: 5 } });
  await c.join(room, "viewer");
  client = c;
  describeStatus(c);
  const tick = setInterval(() => c.state === "joined" && describeStatus(c), 1000);
  try {
    for await (const ev of c) {
      buffers.feed(ev); // poses, leaves, welcomes
      switch (ev.type) {
        case "welcome":
          models.feed(ev);
          for (const player of [...avatars.keys()]) if (!c.members.has(player)) removeAvatar(player);
          for (const mem of c.members.values()) avatarFor(mem.player, mem.name);
          describeStatus(c);
          break;
        case "presence":
          models.feed(ev);
          if (ev.event === "leave") removeAvatar(ev.player);
          else {
            const avatar = avatarFor(ev.player, ev.name);
            avatar.item.classList.toggle("stale", ev.event === "stale");
          }
          describeStatus(c);
          break;
        case "reconnecting":
          setStatus(`connection lost (${ev.cause.code}); retrying in ${ev.delayS.toFixed(1)} s`, true);
          break;
        case "error":
          setStatus(`${ev.error.code}: ${ev.error.message}`, true);
          break;
        case "pose":
          break; // drawn from client.poses each frame
      }
    }
    setStatus("disconnected", true);
  } finally {
    clearInterval(tick);
  }
}

requestAnimationFrame(loop);
void refreshRooms();
run().catch((err: unknown) => {
  if (err instanceof NoTokenError) explainToken();
  const text = err instanceof PosecastError ? `${err.code}: ${err.message}` : String(err);
  setStatus(text, true);
});
