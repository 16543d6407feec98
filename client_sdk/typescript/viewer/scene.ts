/**
 * The three.js stage: renderer, scene, camera and orbit controls on the page's canvas,
 * lights, and a floor grid that moves with the players.
 */

import {
  AmbientLight,
  BufferGeometry,
  Color,
  DirectionalLight,
  Float32BufferAttribute,
  HemisphereLight,
  LineBasicMaterial,
  LineSegments,
  PerspectiveCamera,
  Scene,
  WebGLRenderer,
} from "three";
import { OrbitControls } from "three/addons/controls/OrbitControls.js";

import { $ } from "./page.js";

export const canvas = $<HTMLCanvasElement>("scene");
export const renderer = new WebGLRenderer({ canvas, antialias: true });
renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
export const scene = new Scene();
scene.background = new Color("#15171c");
export const camera = new PerspectiveCamera(50, 1, 0.05, 200);
camera.position.set(3.2, 2.2, 4.2); // an oblique view: walkers side by side stay apart
export const controls = new OrbitControls(camera, canvas);
controls.target.set(0, 1, 0);
controls.enableDamping = true;
scene.add(new HemisphereLight("#ffffff", "#30343c", 1.6));
scene.add(new AmbientLight("#ffffff", 0.5));
const sun = new DirectionalLight("#ffffff", 1.4);
sun.position.set(3, 6, 4);
scene.add(sun);
export const grid = floorGrid(30, "#30343d", "#4a4f5a"); // 1 m squares, moved with the players
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

/** Fit the drawing buffer and the camera to the canvas's size on the page. */
export function resize(): void {
  const w = canvas.clientWidth;
  const h = canvas.clientHeight;
  if (canvas.width !== Math.round(w * renderer.getPixelRatio()) || camera.aspect !== w / h) {
    renderer.setSize(w, h, false);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
  }
}
