/**
 * The frame loop: every display frame, each player's pose for now (sampled from its
 * jitter buffer on the display clock), drawn in the panel's mode; the camera follows the
 * players; the name labels float above their heads.
 */

import { Vector3 } from "three";

import type { PosecastClient } from "../src/index.js";
import { Joint } from "../src/messages.js";
import { mode } from "./hud.js";
import { buffers, client, skeletonOf } from "./network.js";
import { params } from "./page.js";
import { avatarFor, avatars, type Drawn, models, place } from "./players.js";
import { camera, canvas, controls, grid, renderer, resize, scene } from "./scene.js";
import { type Track, trackModels } from "./tracking.js";

const LABEL_ABOVE_HEAD_M = 0.28;

/** The loop's count and switches, which the debug hooks (`debug.ts`) read and turn. */
export const loop = {
  /** Frames drawn so far. */
  frames: 0,
  /** While the benchmark runs (`posecastViewer.bench`), the page draws nothing. */
  benching: false,
  /**
   * Debug switch (`?interp=off`, `posecastViewer.interpolate`): off, each frame draws the
   * newest pose as streamed (the checks compare the models with streamed positions).
   */
  interpolate: params.get("interp") !== "off",
  /**
   * Debug hook: freezing draws the newest poses as they were streamed (not the jitter
   * buffer's samples, whose positions and rotations part during an extrapolation) once,
   * then keeps drawing them (and the camera stays), so checks compare the mesh with the
   * streamed joints.
   */
  frozen: false,
  freezing: false,
  /** While `posecastViewer.track` runs: what it gathers (`tracking.ts`). */
  tracking: undefined as Map<string, Track> | undefined,
};

/**
 * Each player's pose for this frame: sampled at the server's time now once the clock is
 * synced, on the display clock, which slews the offset estimate's steps (up to tens of
 * ms when the best ping leaves the window) instead of moving every avatar by them.
 */
function posesNow(c: PosecastClient | undefined): ReadonlyMap<string, Drawn> {
  if (c === undefined) return new Map();
  if (c.clock.offsetS === undefined || !loop.interpolate) return c.poses; // displayTime throws until the first pong
  return buffers.posesAt(c.clock.displayTime(performance.now() / 1000));
}
const centroid = new Vector3();
const follow = new Vector3();
const head = new Vector3();

function draw(): void {
  resize();
  let n = 0;
  centroid.set(0, 0, 0);
  const poses = loop.freezing
    ? (client?.poses ?? new Map<string, Drawn>())
    : loop.frozen
      ? new Map<string, Drawn>()
      : posesNow(client);
  if (mode === "model" && (loop.freezing || !loop.frozen) && !loop.benching) {
    models.update(poses, skeletonOf); // fits on a new skeleton, hides a model without a pose
  }
  loop.freezing = false;
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
    const pose = loop.frozen ? avatar.shown?.pose : poses.get(avatar.player);
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
  if (loop.tracking !== undefined) trackModels(loop.tracking);
  loop.frames++;
}

/** Draw every display frame (but not while the benchmark runs). */
export function frameLoop(): void {
  if (!loop.benching) draw();
  requestAnimationFrame(frameLoop);
}
