/**
 * Quaternion slerp on flat xyzw arrays (length 4 * J), for the jitter buffer
 * (`interp.ts`): {@link slerpInto} writes into a caller's array, {@link quatSlerp}
 * returns a new one.
 */

/** `out` (length 4 * J) set to the per-joint slerp of `q0` and `q1` at `u` (see {@link quatSlerp}). */
export function slerpInto(q0: ArrayLike<number>, q1: ArrayLike<number>, u: number, out: Float64Array): void {
  for (let j = 0; j < q0.length; j += 4) {
    // Not Math.hypot: a call to it boxes its arguments (garbage every frame).
    const n0 = Math.sqrt(q0[j]! * q0[j]! + q0[j + 1]! * q0[j + 1]! + q0[j + 2]! * q0[j + 2]! + q0[j + 3]! * q0[j + 3]!);
    const n1 = Math.sqrt(q1[j]! * q1[j]! + q1[j + 1]! * q1[j + 1]! + q1[j + 2]! * q1[j + 2]! + q1[j + 3]! * q1[j + 3]!);
    let dot = 0;
    for (let k = 0; k < 4; k++) dot += (q0[j + k]! / n0) * (q1[j + k]! / n1);
    const sign = dot < 0 ? -1 : 1; // the same rotation, on q0's hemisphere
    const omega = Math.acos(Math.min(Math.abs(dot), 1));
    const sin = Math.sin(omega);
    let w0 = 1 - u;
    // `+ 0` makes w1 a number computed here: merged with the sine branch, the argument
    // itself would make V8 box the sine's result on every call (garbage every frame).
    let w1 = u + 0;
    if (sin >= 1e-6) {
      // Nearly equal rotations keep the lerp weights: the sines would cancel badly.
      w0 = Math.sin((1 - u) * omega) / sin;
      w1 = Math.sin(u * omega) / sin;
    }
    let norm = 0;
    for (let k = 0; k < 4; k++) {
      const v = (w0 * q0[j + k]!) / n0 + (sign * w1 * q1[j + k]!) / n1;
      out[j + k] = v;
      norm += v * v;
    }
    norm = Math.sqrt(norm);
    for (let k = 0; k < 4; k++) out[j + k] = out[j + k]! / norm;
  }
}

/**
 * Spherical interpolation of every xyzw quaternion in `q0` and `q1` (length 4 * J) on
 * the shorter arc; `u` outside [0, 1] extrapolates along the same great circle.
 * Inputs need not be unit.
 */
export function quatSlerp(q0: ArrayLike<number>, q1: ArrayLike<number>, u: number): Float64Array {
  const out = new Float64Array(q0.length);
  slerpInto(q0, q1, u, out);
  return out;
}
