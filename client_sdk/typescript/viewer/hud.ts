/**
 * The panel over the scene: the status line, the room picker, the avatar-mode button
 * (and the `s` key), and the help shown when no token can be had.
 */

import type { PosecastClient } from "../src/index.js";
import type { ModelKind } from "./humanoid.js";
import { $, params, room } from "./page.js";

const status = $<HTMLDivElement>("status");
const roomInput = $<HTMLInputElement>("room");
roomInput.value = room;

// --- avatar mode ----------------------------------------------------------------------------

/**
 * `model`: the humanoid model (the default); `mesh`: the procedural skinned body; (both:
 * poses without rotations fall back to sticks); `sticks`: the stick figure.
 */
export type AvatarMode = "model" | "mesh" | "sticks";
const MODES: readonly AvatarMode[] = ["model", "mesh", "sticks"];
/** The mode the players are drawn in now (only {@link setMode} changes it). */
export let mode: AvatarMode = MODES.find((m) => m === params.get("avatar")) ?? "model";
/** The last mode that was not sticks: the `s` key goes back to it. */
let body: Exclude<AvatarMode, "sticks"> = mode === "sticks" ? "model" : mode;
/** The humanoid model, `?model=vrm|gltf`. */
export const modelKind: ModelKind = params.get("model") === "gltf" ? "gltf" : "vrm";
const modeButton = $<HTMLButtonElement>("avatar-mode");
const nextMode = (m: AvatarMode): AvatarMode => MODES[(MODES.indexOf(m) + 1) % MODES.length]!;

export function setMode(next: AvatarMode): void {
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

// --- status line ----------------------------------------------------------------------------

export function setStatus(text: string, error = false): void {
  status.textContent = text;
  status.classList.toggle("error", error);
}

/** The room, its player count, the protocol version and the round trip. */
export function describeStatus(c: PosecastClient): void {
  const n = c.members.size;
  const rtt = c.clock.rttS;
  setStatus(
    `room ${room} · ${n} player${n === 1 ? "" : "s"} · posecast.v${c.version}` +
      (rtt === undefined ? "" : ` · rtt ${(rtt * 1000).toFixed(0)} ms`),
  );
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
export async function refreshRooms(): Promise<void> {
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

// --- help -----------------------------------------------------------------------------------

/** Say how to get a token, when the server hands out none. */
export function explainToken(): void {
  const help = $<HTMLDivElement>("help");
  help.hidden = false;
  help.innerHTML =
    "This server hands out no viewer tokens (it is not in <code>--dev</code> mode, " +
    "or you are not on its machine). Mint a spectator token for this room, e.g. " +
    "<code>posecast token --role spectator --room ROOM --player viewer-1</code>, " +
    "and open <code>…/viewer/?room=ROOM#token=TOKEN</code>.";
}
