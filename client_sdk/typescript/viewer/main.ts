/**
 * The posecast live viewer: joins a room as a spectator with the SDK and draws every
 * player's 19-joint skeleton in 3D (three.js), with name labels, a player list and a
 * room picker. `scripts/build-viewer.mjs` bundles it into the one file the server
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
  CylinderGeometry,
  DirectionalLight,
  Float32BufferAttribute,
  HemisphereLight,
  InstancedMesh,
  LineBasicMaterial,
  LineSegments,
  Matrix4,
  MeshLambertMaterial,
  PerspectiveCamera,
  Quaternion,
  Scene,
  SphereGeometry,
  Vector3,
  WebGLRenderer,
} from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

import { connect, type PosecastClient, PosecastError, type Pose, type TokenSource } from "../src/index.js";
import { Joint, NUM_JOINTS, PARENTS } from "../src/messages.js";

/** Saturated, well-separated hues on a dark background; players take them in join order. */
const PALETTE = ["#ff7a1a", "#1ec8ff", "#b86bff", "#5fe35f", "#ff4f8b", "#ffd23f", "#3d7bff", "#ff3b30"];
const BONE_RADIUS_M = 0.03;
const JOINT_RADIUS_M = 0.045;
const HEAD_RADIUS_M = 0.11;
const LABEL_ABOVE_HEAD_M = 0.28;
const BONES = PARENTS.map((parent, child) => [parent, child] as const).filter(([p]) => p >= 0);

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

const boneGeometry = new CylinderGeometry(BONE_RADIUS_M, BONE_RADIUS_M, 1, 10, 1); // along +Y
const jointGeometry = new SphereGeometry(1, 14, 10);

interface Avatar {
  readonly player: string;
  readonly color: string;
  readonly bones: InstancedMesh;
  readonly joints: InstancedMesh;
  readonly label: HTMLDivElement;
  readonly item: HTMLLIElement;
  name: string;
}

const avatars = new Map<string, Avatar>();
let colorsUsed = 0;

function avatarFor(player: string, name: string): Avatar {
  const existing = avatars.get(player);
  if (existing !== undefined) {
    if (existing.name !== name) rename(existing, name);
    return existing;
  }
  const color = PALETTE[colorsUsed++ % PALETTE.length]!;
  const material = new MeshLambertMaterial({ color, emissive: color, emissiveIntensity: 0.25 });
  const bones = new InstancedMesh(boneGeometry, material, BONES.length);
  const joints = new InstancedMesh(jointGeometry, material, NUM_JOINTS);
  bones.frustumCulled = joints.frustumCulled = false;
  bones.visible = joints.visible = false; // until the first pose
  scene.add(bones, joints);
  const label = document.createElement("div");
  label.className = "label";
  label.hidden = true;
  labels.append(label);
  const item = document.createElement("li");
  item.dataset["player"] = player;
  item.dataset["color"] = color;
  const avatar: Avatar = { player, color, bones, joints, label, item, name };
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
  scene.remove(a.bones, a.joints);
  a.label.remove();
  a.item.remove();
  avatars.delete(player);
}

const m = new Matrix4();
const q = new Quaternion();
const a3 = new Vector3();
const b3 = new Vector3();
const dir = new Vector3();
const scale = new Vector3();
const UP = new Vector3(0, 1, 0);

function place(avatar: Avatar, pose: Pose): void {
  const p = pose.positions;
  BONES.forEach(([parent, child], i) => {
    a3.set(p[3 * parent]!, p[3 * parent + 1]!, p[3 * parent + 2]!);
    b3.set(p[3 * child]!, p[3 * child + 1]!, p[3 * child + 2]!);
    dir.subVectors(b3, a3);
    const length = dir.length();
    q.setFromUnitVectors(UP, length > 1e-6 ? dir.divideScalar(length) : UP);
    m.compose(a3.add(b3).multiplyScalar(0.5), q, scale.set(1, Math.max(length, 1e-4), 1));
    avatar.bones.setMatrixAt(i, m);
  });
  q.identity();
  for (let j = 0; j < NUM_JOINTS; j++) {
    const r = j === Joint.HEAD ? HEAD_RADIUS_M : JOINT_RADIUS_M;
    m.compose(a3.set(p[3 * j]!, p[3 * j + 1]!, p[3 * j + 2]!), q, scale.set(r, r, r));
    avatar.joints.setMatrixAt(j, m);
  }
  avatar.bones.instanceMatrix.needsUpdate = true;
  avatar.joints.instanceMatrix.needsUpdate = true;
  avatar.bones.visible = avatar.joints.visible = true;
}

// --- the frame loop -------------------------------------------------------------------------

let client: PosecastClient | undefined;
let frames = 0;
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

function draw(): void {
  resize();
  let n = 0;
  centroid.set(0, 0, 0);
  for (const [player, pose] of client?.poses ?? []) {
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
    const pose = client?.poses.get(avatar.player);
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
  frames++;
}

function loop(): void {
  draw();
  requestAnimationFrame(loop);
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
    players: () =>
      [...avatars.values()].map((a) => ({
        player: a.player,
        name: a.name,
        color: a.color,
        drawn: a.bones.visible,
      })),
  },
});

// --- the connection -------------------------------------------------------------------------

function describeStatus(c: PosecastClient): void {
  const n = c.members.size;
  const rtt = c.clock.rttS;
  setStatus(
    `room ${room} · ${n} player${n === 1 ? "" : "s"}` +
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
      switch (ev.type) {
        case "welcome":
          for (const player of [...avatars.keys()]) if (!c.members.has(player)) removeAvatar(player);
          for (const mem of c.members.values()) avatarFor(mem.player, mem.name);
          describeStatus(c);
          break;
        case "presence":
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
