"""What one ``hello``'s token check costs: ``verify`` (header, key by kid, signature,
claims) timed with :mod:`timeit` for each algorithm a server verifies, on a key set
holding one key of each kind, and one refused token (a wrong signature, what a
prober sends) of each.

    python benchmarks/token_verify.py            # best of 40 runs of 200 each
    python benchmarks/token_verify.py --number 1000 --repeat 5

Prints microseconds per verification (the best run: the least disturbed by other
work on the machine) and the hellos per second one core could check at that cost.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import platform
import time
import timeit

from posecast.online.auth.keys import SigningKey, generate, parse_key_set
from posecast.online.auth.tokens import UnauthenticatedError, mint, verify


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--number", type=int, default=200, help="verifications per run")
    ap.add_argument("--repeat", type=int, default=40, help="runs; the best is reported")
    args = ap.parse_args()

    pairs = {alg: generate(alg, f"k-{alg}") for alg in ("HS256", "ES256", "EdDSA")}
    keys = parse_key_set(json.dumps({"keys": [pub for _, pub in pairs.values()]}), "bench")
    now = time.time()
    print(f"python {platform.python_version()} on {platform.machine()}")
    print(f"{'alg':6} {'accepted us':>12} {'refused us':>11} {'hellos/s/core':>14}")
    for alg, (private, _) in pairs.items():
        key = SigningKey.from_jwk(private)
        good = mint(key, room="lobby", player="ada", now=now)
        other = SigningKey.from_jwk(generate(alg, f"k-{alg}")[0])  # same kid, other key
        bad = mint(other, room="lobby", player="ada", now=now)
        try:
            verify(keys, bad, now=now)
            raise SystemExit(f"{alg}: a token of another key verified")
        except UnauthenticatedError:
            pass

        def refused(token: str = bad) -> None:
            with contextlib.suppress(UnauthenticatedError):
                verify(keys, token, now=now)

        ok_s = min(
            timeit.repeat(lambda t=good: verify(keys, t, now=now), number=args.number,
                          repeat=args.repeat)
        ) / args.number  # fmt: skip
        bad_s = min(timeit.repeat(refused, number=args.number, repeat=args.repeat)) / args.number
        print(f"{alg:6} {ok_s * 1e6:12.1f} {bad_s * 1e6:11.1f} {1 / ok_s:14,.0f}")


if __name__ == "__main__":
    main()
