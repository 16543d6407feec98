/**
 * The connection: joins the room as a spectator with the SDK (protocol v2, falling back
 * to v1; the status line names the version), reconnects, and reads the events: poses
 * into every player's jitter buffer, presence and welcomes into the players and their
 * models, losses and errors onto the status line.
 *
 * Token: the one in the page's address (`page.ts`), or else a short-lived spectator token
 * for the room from the server's dev-only `token` endpoint (`posecast serve --dev`,
 * loopback clients only), asked again on every reconnect.
 */

import { connect, Interpolator, type PosecastClient, type TokenSource } from "../src/index.js";
import { describeStatus, setStatus } from "./hud.js";
import { room, urlToken, wsUrl } from "./page.js";
import { avatarFor, avatars, models, removeAvatar } from "./players.js";

/** The server hands out no dev token (not `--dev`, or not on its machine). */
export class NoTokenError extends Error {}

const devToken = async (): Promise<string> => {
  const res = await fetch(`token?room=${encodeURIComponent(room)}`, { cache: "no-store" });
  if (!res.ok) throw new NoTokenError(`no dev token (HTTP ${res.status})`);
  return ((await res.json()) as { token: string }).token;
};
const token: TokenSource = urlToken ?? devToken;

/** The client, once joined (only {@link run} sets it). */
export let client: PosecastClient | undefined;
/** v2: the bone offsets of `player` as last announced. */
export const skeletonOf = (player: string): Float64Array | undefined => client?.skeletonOf(player);
/** Every player's jitter buffer: poses arrive at 60 Hz or less, unevenly; frames come at the display's rate. */
export const buffers = new Interpolator();

/** Connect, join and read the events until the stream ends. */
export async function run(): Promise<void> {
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
