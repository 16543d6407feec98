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
 *
 * The modules, in the order they start: `page.ts` (the address, the token in it, the
 * DOM), `hud.ts` (status line, room picker, avatar mode), `scene.ts` (the three.js
 * stage), `players.ts` (an avatar per player, drawn in the mode asked for),
 * `network.ts` (the client and its events), `tracking.ts` and `frame.ts` (the frame
 * loop), `debug.ts` (`window.posecastViewer`); this one starts them.
 */

import { PosecastError } from "../src/index.js";
import { installHooks } from "./debug.js";
import { frameLoop } from "./frame.js";
import { explainToken, refreshRooms, setStatus } from "./hud.js";
import { NoTokenError, run } from "./network.js";

installHooks();
requestAnimationFrame(frameLoop);
void refreshRooms();
run().catch((err: unknown) => {
  if (err instanceof NoTokenError) explainToken();
  const text = err instanceof PosecastError ? `${err.code}: ${err.message}` : String(err);
  setStatus(text, true);
});
