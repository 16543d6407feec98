// posecast in WebXR: connect, stream this headset, show everyone else as a VRM avatar.
// Open index.html#ws=wss://HOST/&token=TOKEN&room=ROOM. Without WebXR, it replays a recording.
import { VRMLoaderPlugin, type VRM } from "@pixiv/three-vrm";
import { connect, type FrameInput, fromXRFrame, Interpolator } from "@posecast/client";
import { AvatarRoom, humanoidFromVRM } from "@posecast/client/three";
import { Color, HemisphereLight, PerspectiveCamera, Scene, WebGLRenderer } from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";

const hash = new URLSearchParams(location.hash.slice(1));
const client = await connect(hash.get("ws") ?? `wss://${location.host}/`, hash.get("token") ?? "");
await client.join(hash.get("room") ?? "demo", "web player", "hmd3"); // headset + 2 controllers

const renderer = new WebGLRenderer({ antialias: true });
renderer.setSize(innerWidth, innerHeight);
renderer.xr.enabled = true;
document.body.append(renderer.domElement);
const scene = new Scene();
scene.background = new Color("#20232a");
scene.add(new HemisphereLight("#ffffff", "#404040", 2));
const camera = new PerspectiveCamera(60, innerWidth / innerHeight, 0.05, 100);
camera.position.set(0, 1.6, 3);

// One avatar per other player, on presence; each its own copy of the model.
const loader = new GLTFLoader().register((parser) => new VRMLoaderPlugin(parser));
const room = new AvatarRoom({
  parent: scene,
  create: async () => {
    const vrm = (await loader.loadAsync("avatar.vrm")).userData["vrm"] as VRM;
    if (vrm.meta.metaVersion === "0") vrm.scene.rotation.y = Math.PI; // VRM 0.x faces -Z (VRMUtils.rotateVRM0)
    return humanoidFromVRM(vrm);
  },
});
const buffers = new Interpolator();
void (async () => {
  for await (const ev of client) [buffers.feed(ev), room.feed(ev)];
})();

// WebXR where the browser has it; elsewhere replay a recorded walk as this player's headset.
const xr = (await navigator.xr?.isSessionSupported("immersive-vr")) === true;
const replay = xr ? undefined : ((await (await fetch("recording.json")).json()) as { rate_hz: number; frames: FrameInput[] });
if (xr) {
  const enter = document.body.appendChild(document.createElement("button"));
  enter.textContent = "enter VR";
  enter.onclick = async () => renderer.xr.setSession(await navigator.xr!.requestSession("immersive-vr", { requiredFeatures: ["local-floor"] }));
}

renderer.setAnimationLoop((time, frame) => {
  const space = renderer.xr.getReferenceSpace();
  if (frame !== undefined && space !== null) client.sendFrame(fromXRFrame(frame, space));
  else if (replay !== undefined) client.sendFrame(replay.frames[Math.floor((time / 1000) * replay.rate_hz) % replay.frames.length]!);
  if (client.clock.offsetS !== undefined) {
    room.update(buffers.posesAt(client.clock.displayTime(time / 1000)), (p) => client.skeletonOf(p));
  }
  renderer.render(scene, camera);
});
